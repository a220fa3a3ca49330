"""``nuav2 convert av2``: several logs, workers, a failing log, resume after a kill, byte-identical tables."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from nuscenes.nuscenes import NuScenes
from test_writer_support import link_log

from nuav2.cli import main
from nuav2.convert import ConvertOptions
from nuav2.nuscenes_db.scene_names import scene_names_for
from nuav2.nuscenes_db.shards import SHARDS_DIRNAME
from nuav2.nuscenes_db.tables import TABLE_NAMES

VERSION = "v1.0-nuav2"
GOOD = ["00000001-0510-35b0-a2fa-b4cea13a6d76", "00000002-0510-35b0-a2fa-b4cea13a6d76"]
BAD = "00000003-0510-35b0-a2fa-b4cea13a6d76"


def _tables(out: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted((out / VERSION).iterdir())}


def _convert(src: Path, out: Path, calib: Path, *extra: str) -> int:
    return main(["convert", "av2", str(src), str(out), "--calibration", str(calib), "--allow-missing-cameras",
                 "--no-progress", *extra])


def test_failing_log_is_reported_and_a_killed_run_resumes_to_identical_tables(
        av2_fixture_log: Path, av2_fixture_calibration: Path, tmp_path: Path, capsys):
    src = tmp_path / "sensor" / "train"
    for log_id in GOOD:
        link_log(av2_fixture_log, src, log_id)
    bad = link_log(av2_fixture_log, src, BAD)
    sweep = next((bad / "sensors" / "lidar").iterdir())
    sweep.unlink()
    sweep.write_bytes(b"this is not a feather file")
    out = tmp_path / "out"

    assert _convert(src, out, av2_fixture_calibration, "--workers", "2") == 1  # 1: some logs failed
    captured = capsys.readouterr()
    assert json.loads(captured.out.strip().splitlines()[-1])["converted"] == 2
    report = json.loads((out / "convert_report.json").read_text())
    assert [f["log_id"] for f in report["failed"]] == [BAD]
    assert str(sweep.name) in report["failed"][0]["error"]
    assert not list((out / "samples" / "LIDAR_TOP").glob(f"{BAD}__*"))  # its partial output was removed
    nusc = NuScenes(VERSION, str(out), verbose=False)
    names = [(s["name"], s["description"]) for s in nusc.scene]
    want = scene_names_for(GOOD)  # stable per log, outside nuScenes' scene-0001..1110 (test_scene_names)
    assert names == sorted((want[x], x) for x in GOOD)
    assert len(nusc.map) == 2 and {m["log_tokens"][0] for m in nusc.map} == {lg["token"] for lg in nusc.log}
    splits = json.loads((out / VERSION / "splits.json").read_text())
    assert splits["av2_train"] == sorted(want.values())
    first = _tables(out)
    assert set(first) >= {f"{t}.json" for t in TABLE_NAMES}

    # Simulate a kill: one shard gone, the merged tables gone, a half-written shard and data file left behind.
    shard_root = out / SHARDS_DIRNAME / VERSION
    shutil.rmtree(shard_root / GOOD[1])
    shutil.rmtree(out / VERSION)
    (shard_root / f".{GOOD[1]}.abc.partial").mkdir()
    pcd = next((out / "samples" / "LIDAR_TOP").glob(f"{GOOD[1]}__*"))
    size = pcd.stat().st_size
    pcd.write_bytes(b"\0" * 10)
    assert _convert(src, out, av2_fixture_calibration) == 1
    report = json.loads((out / "convert_report.json").read_text())
    assert report["resumed"] == [GOOD[0]] and report["converted"] == [GOOD[1]]
    assert pcd.stat().st_size == size
    assert _tables(out) == first

    # Nothing left to do: every good log resumes, the merge alone rewrites the same bytes.
    assert _convert(src, out, av2_fixture_calibration) == 1
    assert json.loads((out / "convert_report.json").read_text())["resumed"] == GOOD
    assert _tables(out) == first


def test_missing_cameras_fail_the_log_and_nothing_is_written(av2_fixture_log: Path,
                                                            av2_fixture_calibration: Path, tmp_path: Path,
                                                            capsys):
    src = link_log(av2_fixture_log, tmp_path / "src", GOOD[0])
    out = tmp_path / "out"
    code = main(["convert", "av2", str(src), str(out), "--calibration", str(av2_fixture_calibration),
                 "--no-progress"])
    assert code == 2
    assert "no log converted" in capsys.readouterr().err
    report = json.loads((out / "convert_report.json").read_text())
    assert "cameras" in report["failed"][0]["error"] and not (out / VERSION).exists()


def test_options_that_change_shards_change_the_fingerprint(tmp_path: Path):
    base = ConvertOptions()
    assert base.fingerprint() == ConvertOptions(workers=4, show_progress=False).fingerprint()
    for other in (ConvertOptions(keyframe_hz=2.0), ConvertOptions(image_link="symlink"),
                  ConvertOptions(require_cameras=False), ConvertOptions(calibration_dir=tmp_path)):
        assert other.fingerprint() != base.fingerprint()


@pytest.mark.parametrize("argv, message", [
    (["--keyframe-hz", "0"], "--keyframe-hz"),
    (["--keyframe-hz", "inf"], "--keyframe-hz"),
    (["--workers", "0"], "--workers"),
    (["--version", "../x"], "--version"),
    (["--mode", "warp", "--scale", "inf"], "--scale must be a finite number"),
    (["--mode", "warp", "--scale", "1e-9"], "smaller than 8 px"),
])
def test_bad_arguments_are_clear_errors(av2_fixture_log: Path, tmp_path: Path, capsys, argv, message):
    assert main(["convert", "av2", str(av2_fixture_log), str(tmp_path / "o"), "--no-progress", *argv]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists()
