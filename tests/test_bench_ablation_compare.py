"""``nuav2 bench ablation --before``: two ablations side by side, factor by factor, with the robustness
goals judged on the same numbers (on a tiny warp-only run the CLI really writes)."""

from __future__ import annotations

import json

import pytest

from nuav2.bench.ablation_compare import compare_markdown, goals, lost_db, recovered_share
from nuav2.cli import main as cli_main


def test_recovered_share():
    assert recovered_share(2.0, 0.5) == pytest.approx(0.75)
    assert recovered_share(2.0, 2.5) == pytest.approx(-0.25)  # worse after
    assert recovered_share(0.01, 0.5) is None and recovered_share(None, 1.0) is None  # nothing to recover


def test_cli_compares_a_saved_run_with_itself(tmp_path, capsys):
    out, md = tmp_path / "run.json", tmp_path / "table.md"
    args = ["bench", "ablation", "--seeds", "0", "--factors", "exposure", "--presets", "", "--seconds", "0.3",
            "--image-scale", "0.0625", "--scale", "0.1", "--modes", "warp", "--speed-seconds", "0"]
    assert cli_main([*args, "--out", str(out), "--json"]) == 0
    capsys.readouterr()
    run = json.loads(out.read_text())
    lost = lost_db(run, "+exposure", "warp")
    assert lost == pytest.approx(-run["rows"]["+exposure"]["warp"]["delta"]["psnr_db_whole"])
    assert cli_main(["bench", "ablation", "--from-json", str(out), "--before", str(out),
                     "--markdown", str(md), "--json"]) == 0
    printed = json.loads(capsys.readouterr().out)
    by_goal = {(g["goal"], g["mode"]): g for g in printed["goals"]}
    same = by_goal[("recover >= 2/3 of the dB exposure costs", "warp")]
    assert same["lost_before_db"] == same["lost_after_db"] == pytest.approx(lost)
    assert same["met"] == (lost <= 0.05)  # the same run recovers nothing
    assert by_goal[("exposure alone costs < 0.5 dB after compensation", "warp")]["met"] == (lost < 0.5)
    assert by_goal[("recover >= 2/3 of the dB label_noise costs", "warp")]["met"] is None  # not run
    assert by_goal[("hard: render ground PSNR within 2.0 dB of easy", "render")]["met"] is None
    text = md.read_text()
    assert f"| +exposure | {lost:.2f} → {lost:.2f}" in text
    assert "| goal | mode | before | after | met |" in text and "not measured" in text
    assert compare_markdown(run, run) in text and len(goals(run, run)) == len(printed["goals"])
    missing = str(tmp_path / "none.json")
    assert cli_main(["bench", "ablation", "--from-json", str(out), "--before", missing]) == 2
    assert "--before" in capsys.readouterr().err


def test_from_json_merges_a_later_runs_modes(tmp_path, capsys):
    """Two real runs of the same seed: the later one's warp columns (here at another target scale, so they
    differ) replace the earlier one's, its extra row joins; runs of other seeds do not merge."""
    base = ["bench", "ablation", "--presets", "", "--seconds", "0.3", "--image-scale", "0.0625",
            "--modes", "warp", "--speed-seconds", "0", "--json"]
    first, later, other = tmp_path / "first.json", tmp_path / "later.json", tmp_path / "other.json"
    exposure = ["--factors", "exposure", "--scale", "0.1"]
    assert cli_main([*base, "--seeds", "0", *exposure, "--out", str(first)]) == 0
    assert cli_main([*base, "--seeds", "0", "--factors", "exposure,lidar_noise", "--scale", "0.08",
                     "--out", str(later)]) == 0
    capsys.readouterr()
    assert cli_main(["bench", "ablation", "--from-json", str(first), str(later), "--json"]) == 0
    merged = json.loads(capsys.readouterr().out)
    a, b = json.loads(first.read_text()), json.loads(later.read_text())
    assert a["rows"]["easy"]["warp"] != b["rows"]["easy"]["warp"]
    assert merged["rows"]["easy"]["warp"] == b["rows"]["easy"]["warp"]
    warp_of = [r["per_seed"]["+exposure"][0]["modes"]["warp"] for r in (merged, b)]
    assert warp_of[0] == warp_of[1]
    assert set(merged["rows"]) == {"easy", "+exposure", "+lidar_noise"}
    assert a["command"] in merged["command"] and b["command"] in merged["command"]
    assert cli_main([*base, "--seeds", "1", *exposure, "--out", str(other)]) == 0
    capsys.readouterr()
    assert cli_main(["bench", "ablation", "--from-json", str(first), str(other)]) == 2
    assert "seeds" in capsys.readouterr().err
