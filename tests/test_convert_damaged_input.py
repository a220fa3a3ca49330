"""Conversions of awkward input: an empty LiDAR sweep, `.` as SRC, a log converted again with other
options into the same OUT, an unreadable log folder in a batch, and a batch where every log fails."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pyarrow.feather as feather
from e2e_helpers import VERSION, cli, cli_bound_by_modes, convert, table, umask

pytest_plugins = ["test_writer_support", "e2e_support"]


def _data_files(out: Path) -> set[str]:
    return {str(p.relative_to(out)) for top in ("samples", "sweeps") if (out / top).is_dir()
            for p in (out / top).rglob("*") if p.is_file()}


def _empty_dirs(out: Path) -> list[str]:
    return [str(p) for top in ("samples", "sweeps") if (out / top).is_dir()
            for p in (out / top).rglob("*") if p.is_dir() and not any(p.iterdir())]


def test_an_empty_lidar_sweep_converts_to_a_file_the_validator_and_devkit_accept(synth_log: Path,
                                                                                  tmp_path: Path):
    from nuscenes.utils.data_classes import LidarPointCloud

    src = tmp_path / "src" / "train" / synth_log.name
    shutil.copytree(synth_log, src)
    sweep = sorted((src / "sensors" / "lidar").iterdir())[2]
    feather.write_feather(feather.read_table(sweep).slice(0, 0), sweep)
    out = tmp_path / "out"
    convert(src.parent, out)
    (empty,) = [r for r in table(out, "sample_data")
                if r["filename"].endswith(".pcd.bin") and (out / r["filename"]).stat().st_size == 0]
    assert LidarPointCloud.from_file(str(out / empty["filename"])).points.shape == (4, 0)
    code, stdout, stderr = cli("validate", out, "--version", VERSION, "--devkit", "--quiet")
    assert code == 0, stdout + stderr


def test_dot_as_src_takes_the_log_id_from_the_folder(synth_log: Path, tmp_path: Path, monkeypatch):
    monkeypatch.chdir(synth_log)
    out = tmp_path / "out"
    convert(Path("."), out)
    assert [s["description"] for s in table(out, "scene")] == [synth_log.name]


def test_converting_a_log_again_with_other_options_leaves_no_orphan_files(synth_log: Path, tmp_path: Path):
    """native -> warp (other channels) -> native at 2 Hz (other sample/sweep folders) into one OUT:
    each run's database lists exactly the data files on disk, and no empty folder is left."""
    out = tmp_path / "out"
    for flags in ((), ("--mode", "warp", "--rig", "nuscenes", "--scale", "0.125"), ("--keyframe-hz", "2")):
        convert(synth_log.parent, out, *flags)
        assert _data_files(out) == {r["filename"] for r in table(out, "sample_data")}, flags
        assert _empty_dirs(out) == []


def test_a_batch_where_every_log_fails_says_why_in_one_line(synth_log: Path, tmp_path: Path):
    src = tmp_path / "src" / "train" / synth_log.name
    shutil.copytree(synth_log, src)
    (src / "city_SE3_egovehicle.feather").write_bytes(b"not a feather file")
    out = tmp_path / "out"
    code, _, err = cli("convert", "av2", src.parent, out, "--no-progress")
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1, err
    assert lines[0].startswith(f"nuav2 convert: no log converted: {src}: ")
    assert "city_SE3_egovehicle" in lines[0]
    assert _empty_dirs(out) == [] and not (out / "samples").exists()
    assert json.loads((out / "convert_report.json").read_text())["failed"][0]["log_id"] == synth_log.name


def test_an_unreadable_log_folder_fails_alone(synth_log: Path, tmp_path: Path):
    split = tmp_path / "src" / "train"
    shutil.copytree(synth_log, split / synth_log.name)
    (split / "locked").mkdir()
    (split / "locked").chmod(0)
    try:
        out = tmp_path / "out"
        with umask(0o022):
            code, _, err = cli_bound_by_modes("convert", "av2", split, out, "--no-progress")
    finally:
        (split / "locked").chmod(0o755)
    assert code == 1 and "locked" in err and "Permission denied" in err
    assert [s["description"] for s in table(out, "scene")] == [synth_log.name]


def test_a_failed_reconversion_never_lets_the_old_shard_be_resumed(synth_log: Path, tmp_path: Path):
    """Converted once; converted again with other options but failing half-way (a damaged image),
    whose cleanup removes files it had overwritten; then converted with the first options again:
    the old shard must be redone, not resumed over files that are gone."""
    src = tmp_path / "src" / "train" / synth_log.name
    shutil.copytree(synth_log, src)
    out = tmp_path / "out"
    convert(src.parent, out, "--image-link", "copy")
    images = sorted((src / "sensors" / "cameras" / "ring_rear_right").iterdir())
    images[-1].write_bytes(images[-1].read_bytes()[:200])  # the last camera's last image: a late failure
    code, _, err = cli("convert", "av2", src.parent, out, "--image-link", "symlink", "--no-progress")
    assert code == 2 and "ring_rear_right" in err
    shutil.copyfile(synth_log / images[-1].relative_to(src), images[-1])
    code, stdout, _ = cli("convert", "av2", src.parent, out, "--image-link", "copy", "--no-progress")
    assert code == 0 and json.loads(stdout)["resumed"] == 0 and json.loads(stdout)["converted"] == 1
    assert _data_files(out) == {r["filename"] for r in table(out, "sample_data")}
    code, stdout, stderr = cli("validate", out, "--version", VERSION, "--quiet")
    assert code == 0, stdout + stderr
