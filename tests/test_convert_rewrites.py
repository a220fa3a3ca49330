"""Converting a log again into an OUT that already holds a database, and logs that cannot convert:
no table may name a file that is gone or that another conversion overwrote, and one bad log (a
name no shard can have, a missing pose file) fails alone, listed in the report."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from e2e_helpers import FIXTURE_ID, VERSION, cli, convert

pytest_plugins = ["test_writer_support", "e2e_support"]


def _copy_split(log_dir: Path, split_dir: Path, *names: str) -> list[Path]:
    split_dir.mkdir(parents=True)
    return [Path(shutil.copytree(log_dir, split_dir / name)) for name in names]


def _validates(out: Path, version: str = VERSION) -> None:
    code, stdout, stderr = cli("validate", out, "--version", version, "--json")
    assert code == 0 and json.loads(stdout)["ok"] is True, stdout + stderr


def _data_files(out: Path) -> set[str]:
    return {str(p.relative_to(out)) for top in ("samples", "sweeps") if (out / top).is_dir()
            for p in (out / top).rglob("*") if p.is_file()}


def test_a_failed_reconversion_leaves_no_tables_naming_removed_files(synth_log: Path, tmp_path: Path, caplog):
    (log_dir,) = _copy_split(synth_log, tmp_path / "src" / "train", synth_log.name)
    out = tmp_path / "out"
    convert(log_dir.parent, out)
    bad = sorted((log_dir / "sensors" / "cameras" / "ring_front_left").iterdir())[0]
    intact = bad.read_bytes()
    bad.write_bytes(intact[: len(intact) // 2])
    with caplog.at_level("WARNING", logger="nuav2.nuscenes_db.rewrites"):
        code, _, err = cli("convert", "av2", log_dir.parent, out, "--keyframe-hz", "2", "--no-progress")
    assert code == 2 and "no log converted" in err, err
    assert f"{out / VERSION}: removing these tables before 1 of their logs are written again" in caplog.text
    # before: the old tables stayed, naming files the failed attempt had overwritten and removed
    assert not (out / VERSION).exists()
    assert _data_files(out) == set()
    bad.write_bytes(intact)
    assert convert(log_dir.parent, out, "--keyframe-hz", "2")["converted"] == 1
    _validates(out)


def test_another_version_converted_otherwise_is_refused_and_one_made_alike_shares(synth_log: Path,
                                                                                  tmp_path: Path):
    out = tmp_path / "out"
    convert(synth_log.parent, out)
    before = {p.name: p.read_bytes() for p in (out / VERSION).iterdir()}
    files = {f: (out / f).read_bytes() for f in _data_files(out)}
    code, _, err = cli("convert", "av2", synth_log.parent, out, "--version", "v1.0-other",
                       "--keyframe-hz", "2", "--no-progress")
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert f"({VERSION}/{synth_log.name})" in err and "other options" in err
    assert {p.name: p.read_bytes() for p in (out / VERSION).iterdir()} == before
    assert {f: (out / f).read_bytes() for f in _data_files(out)} == files  # no image rewritten
    assert not (out / "v1.0-other").exists()
    convert(synth_log.parent, out, "--version", "v1.0-other")  # the same options: the same files
    _validates(out)
    _validates(out, "v1.0-other")


def test_a_badly_named_log_and_a_log_without_poses_fail_alone(synth_log: Path, tmp_path: Path):
    damaged_id = "00000009-0510-35b0-a2fa-b4cea13a6d76"
    good, badly_named, damaged = _copy_split(synth_log, tmp_path / "src" / "train",
                                             synth_log.name, "my log", damaged_id)
    (damaged / "city_SE3_egovehicle.feather").unlink()  # a partial download
    out = tmp_path / "out"
    code, stdout, err = cli("convert", "av2", good.parent, out, "--no-progress")
    assert code == 1 and json.loads(stdout.strip().splitlines()[-1])["converted"] == 1, err
    report = json.loads((out / "convert_report.json").read_text())
    assert report["converted"] == [good.name]
    failed = {f["log_id"]: f["error"] for f in report["failed"]}
    assert failed == {
        "my log": "ValueError: log id 'my log' is not usable as a directory name",
        damaged_id: f"AV2LogError: {damaged / 'city_SE3_egovehicle.feather'}: file not found"}
    assert [f["log_id"] for f in report["failed"]] == sorted(failed)
    assert f"failed: {badly_named}: ValueError" in err
    _validates(out)


def test_logs_whose_ids_would_share_a_map_location_are_refused(synth_log: Path, tmp_path: Path):
    """A map location holds 8 hex digits of the log id: two logs beginning alike would overwrite
    each other's map files; ids that are not AV2's (``run1``, ``run2``) get 8 digits of a hash."""
    from nuav2.nuscenes_db.map_frame import location_for

    assert location_for("PIT", FIXTURE_ID) == "av2-pit-adcf7d18"
    assert location_for("PIT", "run1") != location_for("PIT", "run2")
    alike = ["0badc0de-0000-0000-0000-000000000001", "0badc0de-0000-0000-0000-000000000002"]
    split = tmp_path / "src" / "train"
    _copy_split(synth_log, split, *alike)
    code, _, err = cli("convert", "av2", split, tmp_path / "out", "--no-progress")
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert f"logs {alike[0]} and {alike[1]} would share one map location" in err
    assert not (tmp_path / "out").exists()
    first = tmp_path / "out2"
    shutil.rmtree(split / alike[1])
    convert(split, first)  # one at a time into one OUT: the second is refused too
    shutil.rmtree(split / alike[0])
    _copy_split(synth_log, tmp_path / "src2" / "train", alike[1])
    code, _, err = cli("convert", "av2", tmp_path / "src2" / "train", first, "--no-progress")
    assert code == 2 and f"logs {alike[0]} and {alike[1]} would share" in err, err
    _validates(first)


def test_a_failed_attempt_in_one_version_keeps_the_files_another_version_uses(synth_log: Path,
                                                                               tmp_path: Path):
    (log_dir,) = _copy_split(synth_log, tmp_path / "src" / "train", synth_log.name)
    out = tmp_path / "out"
    convert(log_dir.parent, out)
    convert(log_dir.parent, out, "--version", "v1.0-other")  # same options: the same files
    shutil.rmtree(out / ".nuav2_shards" / "v1.0-other" / log_dir.name)  # so the log is written again
    bad = sorted((log_dir / "sensors" / "cameras" / "ring_front_left").iterdir())[0]
    bad.write_bytes(bad.read_bytes()[:100])
    code, _, err = cli("convert", "av2", log_dir.parent, out, "--version", "v1.0-other", "--no-progress")
    assert code == 2 and "no log converted" in err, err
    _validates(out)  # the failed attempt removed none of the files VERSION's tables name
