"""``nuav2 bench transfer --smoke``: the whole benchmark's plumbing on two tiny worlds, a few steps.

Checks the wiring, not the numbers: worlds -> conversions (native, warp, truth) -> geo splits ->
training through ``nuav2.maptr`` -> ``nuav2 eval`` scores -> tables, figures; and that a rerun
reuses every finished piece.
"""

from __future__ import annotations

import json

import cv2
import pytest

from nuav2.cli import main


@pytest.fixture(scope="module")
def smoke(tmp_path_factory):
    out = tmp_path_factory.mktemp("transfer")
    assert main(["bench", "transfer", "--smoke", "--preset", "easy", "--out", str(out)]) == 0
    return out, json.loads((out / "transfer.json").read_text())


def test_every_run_is_trained_and_scored_by_nuav2_eval(smoke):
    out, result = smoke
    assert set(result["runs"]) == {
        "native-s0",
        "warp-s0",
        "truth-s0",
        "ft100-scratch-s0",
        "ft100-pretrained-s0",
    }
    for name, run in result["runs"].items():
        assert run["steps"] == (2 if name.startswith("ft") else 3)
        assert 0.0 <= run["eval"]["mAP"] <= 1.0
        assert run["eval"]["n_samples"] == result["test_set"]["keyframes"] == 3
        assert run["eval_matches_curve"], name
        saved = json.loads((out / "runs" / name / "eval.json").read_text())
        assert saved["predictions"].endswith("predictions.json")  # written by the nuav2 eval command
    assert result["runs"]["ft100-pretrained-s0"]["init"].endswith("warp-s0/model.pt")
    assert set(result["table1"]) == {"native", "warp", "truth"}
    assert "warp_over_av2" in result["ratios"] and result["ratios"]["warp_over_av2"]["paper"] == 4.25


def test_training_sets_have_their_rigs_and_the_test_worlds_are_held_out(smoke):
    out, result = smoke
    lists = json.loads((out / "world_lists.json").read_text())
    assert len(lists["train"]) == len(lists["test"]) == 1 and not set(lists["train"]) & set(lists["test"])
    cams = {
        r["set"]: json.loads((out / "runs" / k / "run.json").read_text())["data"]["cameras"]
        for k, r in result["runs"].items()
        if "set" in r
    }
    assert len(cams["native"]) == 7 and cams["native"][0].startswith("ring_")
    assert cams["warp"] == cams["truth"] and len(cams["truth"]) == 6
    db = out / "db" / "truth" / "v1.0-nuav2"
    splits = json.loads((db / "splits.json").read_text())
    scenes = {s["name"]: s["description"] for s in json.loads((db / "scene.json").read_text())}
    assert [scenes[s] for s in splits["geo_test"]] == lists["test"]
    assert [scenes[s] for s in splits["geo_train"]] == lists["train"]
    worlds = {w["log_id"]: w for w in result["worlds"]}
    assert {worlds[x]["city"] for x in lists["train"]}.isdisjoint({worlds[x]["city"] for x in lists["test"]})


def test_tables_and_figures_are_written(smoke):
    out, result = smoke
    md = (out / "transfer.md").read_text()
    assert "Table 1 shape" in md and "Table 2 shape" in md and "Verdict" in md and "paper" in md
    img = cv2.imread(result["figures"]["curves"])
    assert img is not None and img.shape[0] > 100
    assert set(result["figures"]["pred_vs_gt"]) == {"native", "warp", "truth"}
    for png in result["figures"]["pred_vs_gt"].values():
        assert cv2.imread(png) is not None


def test_a_rerun_reuses_worlds_conversions_and_runs(smoke):
    out, first = smoke
    stamps = {p: p.stat().st_mtime_ns for p in (out / "runs").glob("*/model.pt")}
    caches = sorted(p.name for p in (out / "cache").glob("maptensors-*.pt"))
    assert main(["bench", "transfer", "--smoke", "--preset", "easy", "--out", str(out), "--no-figures"]) == 0
    again = json.loads((out / "transfer.json").read_text())
    assert not any(w["generated"] for w in again["worlds"])
    assert all(c["converted"] == 0 and c["resumed"] >= 1 for c in again["conversions"].values())
    assert {p: p.stat().st_mtime_ns for p in (out / "runs").glob("*/model.pt")} == stamps
    assert sorted(p.name for p in (out / "cache").glob("maptensors-*.pt")) == caches  # tensors reused
    assert {k: r["eval"]["mAP"] for k, r in again["runs"].items()} == {
        k: r["eval"]["mAP"] for k, r in first["runs"].items()
    }


def test_an_interrupted_benchmark_resumes_what_is_missing_and_reuses_the_rest(smoke):
    """State an interruption leaves: a world log not yet written, merged tables missing beside complete
    shards, a run killed after its last checkpoint but before ``model.pt``, an evaluation not yet written.
    The rerun redoes exactly those and gets the same result."""
    import shutil

    import torch

    out, first = smoke
    lists = json.loads((out / "world_lists.json").read_text())
    shutil.rmtree(out / "worlds" / "val" / lists["test"][0])
    shutil.rmtree(out / "db" / "warp" / "v1.0-nuav2")
    killed = out / "runs" / "truth-s0"
    weights = torch.load(killed / "model.pt", weights_only=True)
    (killed / "model.pt").unlink()
    (killed / "run.json").unlink()
    (out / "runs" / "native-s0" / "eval.json").unlink()
    others = {
        p: p.stat().st_mtime_ns for p in (out / "runs").glob("*/model.pt") if p.parent.name != "truth-s0"
    }

    assert main(["bench", "transfer", "--smoke", "--preset", "easy", "--out", str(out), "--no-figures"]) == 0
    again = json.loads((out / "transfer.json").read_text())
    assert [w["log_id"] for w in again["worlds"] if w["generated"]] == [lists["test"][0]]
    warp = again["conversions"]["warp"]
    assert warp["converted"] == 0 and warp["resumed"] == 1 and warp["samples"] == 3  # tables re-merged
    resumed = torch.load(killed / "model.pt", weights_only=True)
    assert all(torch.equal(weights[k], resumed[k]) for k in weights)  # from checkpoint.pt, not retrained
    assert {p: p.stat().st_mtime_ns for p in others} == others
    assert (out / "runs" / "native-s0" / "eval.json").is_file()
    assert {k: r["eval"]["mAP"] for k, r in again["runs"].items()} == {
        k: r["eval"]["mAP"] for k, r in first["runs"].items()
    }
