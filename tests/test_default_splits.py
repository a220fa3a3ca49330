"""Default splits on a plain nuScenes layout (no splits.json, no nuav2_logs.json, nuScenes scene names):
``nuav2 eval`` and ``nuav2 infos`` use the devkit's lists of the database's own release only.

The layouts are made from real ``nuav2 convert`` output (``two_run_db``: two logs), renamed as a
nuScenes release names its scenes: scene-0553 (v1.0-mini's mini_train, but in trainval's val list)
and scene-0103 (mini_val, and trainval's val).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from e2e_helpers import VERSION, cli, copy_db

pytest_plugins = ["test_writer_support", "e2e_support"]

NAMES = ("scene-0553", "scene-0103")  # mini_train (trainval val), mini_val (trainval val)


def plain_nuscenes(db: Path, dest: Path, version: str) -> Path:
    """``db`` as a plain nuScenes ``version`` dataroot: data linked, tables copied, nuAV2's sidecars
    removed, the scenes renamed to NAMES (in name order)."""
    copy_db(db, dest)
    (dest / VERSION).rename(dest / version)
    for sidecar in ("nuav2_logs.json", "splits.json", "splits_report.json"):
        (dest / version / sidecar).unlink(missing_ok=True)
    path = dest / version / "scene.json"
    scenes = json.loads(path.read_text())
    assert len(scenes) == len(NAMES)
    for rec, name in zip(sorted(scenes, key=lambda r: r["name"]), NAMES):
        rec["name"] = name
    path.write_text(json.dumps(scenes))
    return dest


@pytest.fixture(scope="module")
def mini(two_run_db, tmp_path_factory) -> Path:
    return plain_nuscenes(two_run_db[0], tmp_path_factory.mktemp("plain") / "mini", "v1.0-mini")


@pytest.fixture(scope="module")
def trainval(two_run_db, tmp_path_factory) -> Path:
    return plain_nuscenes(two_run_db[0], tmp_path_factory.mktemp("plain") / "trainval", "v1.0-trainval")


def exact_results(path: Path, db: Path, version: str, split: str) -> Path:
    """A MapTR result file predicting exactly the map GT of ``split``."""
    from nuav2.maptr.vectorize import gt_vectors_for_split

    gts = gt_vectors_for_split(db, version, split)
    results = [{"sample_token": tok, "vectors": [
        {"pts": np.asarray(p).tolist(), "pts_num": len(p), "cls_name": c, "confidence_level": 0.9}
        for c, p in vecs]} for tok, vecs in gts.items()]
    path.write_text(json.dumps({"meta": {}, "results": results}))
    return path


def test_eval_on_v1_0_mini_defaults_to_mini_val_not_trainvals_val(mini: Path, tmp_path: Path):
    """trainval's val list holds both scenes (one of them mini_train): the default must be mini_val,
    as the devkit's and MapTR's evaluation of v1.0-mini use, so mini_val's GT as predictions scores 1."""
    pred = exact_results(tmp_path / "mini_val.json", mini, "v1.0-mini", "mini_val")
    code, out, err = cli("eval", pred, "--dataroot", mini, "--version", "v1.0-mini", "--json")
    assert code == 0, err
    result = json.loads(out)
    assert result["gt_source"].endswith("split mini_val (from the map)")
    assert result["n_samples_without_predictions"] == 0
    assert result["mAP"] == pytest.approx(1.0, abs=1e-9)
    code, out, err = cli("eval", pred, "--dataroot", mini, "--version", "v1.0-mini", "--split", "val",
                         "--json")
    assert code == 0, err  # asked for by name, trainval's val is still there (as in the devkit)
    assert json.loads(out)["n_samples_without_predictions"] > 0


def test_eval_on_v1_0_trainval_defaults_to_val(trainval: Path, tmp_path: Path):
    pred = exact_results(tmp_path / "val.json", trainval, "v1.0-trainval", "val")
    code, out, err = cli("eval", pred, "--dataroot", trainval, "--version", "v1.0-trainval", "--json")
    assert code == 0, err
    assert json.loads(out)["gt_source"].endswith("split val (from the map)")


def test_infos_without_splits_writes_the_releases_lists_with_scenes(mini: Path, trainval: Path,
                                                                   tmp_path: Path):
    """No splits.json: the devkit's lists of the version's own release that hold scenes present,
    not every built-in list (the test list has none of these scenes) nor another release's."""
    import pickle

    expected = {"v1.0-mini": {"mini_train": ["scene-0553"], "mini_val": ["scene-0103"]},
                "v1.0-trainval": {"val": ["scene-0553", "scene-0103"]}}
    for db, version in ((mini, "v1.0-mini"), (trainval, "v1.0-trainval")):
        code, out, err = cli("infos", db, "--version", version, "--out", tmp_path / version, "--no-progress")
        assert code == 0, err
        written = json.loads(out)
        assert set(written) == set(expected[version])
        scenes = {s["token"]: s["name"] for s in json.loads((db / version / "scene.json").read_text())}
        for split, path in written.items():
            with open(path, "rb") as f:
                infos = pickle.load(f)["infos"]
            assert {scenes[i["scene_token"]] for i in infos} == set(expected[version][split])


def test_available_splits_are_those_present_in_the_release(mini: Path):
    from nuav2.maptr.subsets import available_splits, release_splits

    class Index:
        dataroot, version = str(mini), "v1.0-mini"

    assert release_splits(mini, "v1.0-mini") == {"mini_train": ["scene-0553"], "mini_val": ["scene-0103"]}
    assert available_splits(Index) == ["mini_train", "mini_val"]
