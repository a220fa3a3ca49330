"""What a new user hits around ``nuav2 convert`` (issue 10): a second split into the same OUT,
scene names, file modes, damaged images, and one-line errors for bad input on every command."""

from __future__ import annotations

import json
import os
import shutil
import stat
from pathlib import Path

import pytest
from e2e_helpers import (
    FIXTURE_ID,
    VERSION,
    cli,
    cli_bound_by_modes,
    convert,
    imaged_copy,
    logs_meta,
    table,
    umask,
)

pytest_plugins = ["test_writer_support", "e2e_support"]


# ------------------------------------------------------------------ finding 10: two runs, one OUT


def test_second_split_into_the_same_out_keeps_the_first(two_run_db, synth_log: Path, synth_val_log: Path):
    out, (first, second) = two_run_db
    assert first["converted"] == 1 and second["converted"] == 1 and second["merged_earlier"] == 1
    scenes = {s["description"]: s["name"] for s in table(out, "scene")}
    assert set(scenes) == {synth_log.name, synth_val_log.name}
    splits = json.loads((out / VERSION / "splits.json").read_text())
    assert splits["av2_train"] == [scenes[synth_log.name]]
    assert splits["av2_val"] == [scenes[synth_val_log.name]]
    assert sorted(splits["all"]) == sorted(scenes.values())
    assert {m["log_id"] for m in logs_meta(out)} == set(scenes)
    report = json.loads((out / "convert_report.json").read_text())
    assert report["merged_earlier"] == [synth_log.name] and report["converted"] == [synth_val_log.name]


def test_shards_made_with_other_options_are_refused_by_name(two_run_db, synth_val_log: Path, tmp_path: Path):
    out = tmp_path / "out"
    shutil.copytree(two_run_db[0], out, symlinks=True)
    before = {p.name: p.read_bytes() for p in (out / VERSION).iterdir()}
    code, _, err = cli("convert", "av2", synth_val_log.parent, out, "--keyframe-hz", "2", "--no-progress")
    assert code == 2 and len(err.strip().splitlines()) == 1
    train_log = next(m["log_id"] for m in logs_meta(out) if m["split"] == "train")
    assert train_log in err and "other options" in err and "Traceback" not in err
    assert {p.name: p.read_bytes() for p in (out / VERSION).iterdir()} == before  # nothing touched


# ------------------------------------------------------------------ finding 5: scene names


def test_scene_names_avoid_nuscenes_lists_and_do_not_depend_on_other_logs(native_fixture_db, native_synth_db,
                                                                         two_run_db, synth_log: Path):
    from nuscenes.utils.splits import create_splits_scenes

    nuscenes_names = {s for names in create_splits_scenes().values() for s in names}
    (fixture_scene,) = table(native_fixture_db, "scene")
    assert fixture_scene["name"] == "scene-2469"  # 2000 + its index in av2's TRAIN + VAL + TEST
    two = {s["description"]: s["name"] for s in table(two_run_db[0], "scene")}
    alone = {s["description"]: s["name"] for s in table(native_synth_db, "scene")}
    assert two[synth_log.name] == alone[synth_log.name]  # same log, same name, with or without others
    for name in [fixture_scene["name"], *two.values()]:
        assert name not in nuscenes_names and 2000 <= int(name[6:]) <= 9999
    assert all(3000 <= int(n[6:]) <= 9999 for n in two.values())  # synthetic logs are in no av2 list


def test_a_nuscenes_version_name_warns_that_its_devkit_splits_select_none_of_these_scenes(
        synth_log: Path, tmp_path: Path, caplog):
    """``--version v1.0-trainval`` (what mmdet3d configs expect) converts, but the devkit's
    train/val lists of that version, which stock converters and load_gt use, hold none of our
    scenes: the user is told once, with the split keys that do work."""
    from nuscenes.utils.splits import create_splits_scenes

    out = tmp_path / "out"
    assert cli("convert", "av2", synth_log.parent, out, "--version", "v1.0-trainval", "--no-progress")[0] == 0
    warned = [r.getMessage() for r in caplog.records if "v1.0-trainval" in r.getMessage()]
    assert len(warned) == 1 and "av2_train" in warned[0] and "\n" not in warned[0]
    names = {s["name"] for s in json.loads((out / "v1.0-trainval" / "scene.json").read_text())}
    devkit = create_splits_scenes()
    assert names and not names & (set(devkit["train"]) | set(devkit["val"]))
    assert json.loads((out / "v1.0-trainval" / "splits.json").read_text())["av2_train"] == sorted(names)
    caplog.clear()
    assert cli("convert", "av2", synth_log.parent, tmp_path / "own", "--no-progress")[0] == 0
    assert not [r for r in caplog.records if "splits of that version" in r.getMessage()]


def test_a_version_folder_nuav2_did_not_write_is_never_replaced(synth_log: Path, tmp_path: Path):
    """Converting into a real nuScenes dataroot with its own --version replaced its tables whole."""
    out = tmp_path / "nuscenes"
    theirs = out / "v1.0-trainval"
    theirs.mkdir(parents=True)
    (theirs / "scene.json").write_text('[{"token": "a", "name": "scene-0001"}]')
    (theirs / "their_notes.json").write_text("{}")
    code, _, err = cli("convert", "av2", synth_log.parent, out, "--version", "v1.0-trainval", "--no-progress")
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert str(theirs) in err and "nuav2_logs.json" in err and "--version" in err
    assert sorted(p.name for p in out.iterdir()) == ["v1.0-trainval"]  # nothing else written
    assert sorted(p.name for p in theirs.iterdir()) == ["scene.json", "their_notes.json"]


# ------------------------------------------------------------------ finding 7: file modes


@pytest.mark.parametrize("name", ["native_fixture_db", "two_run_db"])
def test_written_files_follow_the_umask(name, request):
    """Converted under umask 022: files 0644, directories 0755, like any ordinary write."""
    value = request.getfixturevalue(name)
    out = value[0] if isinstance(value, tuple) else value
    wrong = []
    for root, dirs, files in os.walk(out):
        for d in dirs:
            mode = stat.S_IMODE(os.lstat(Path(root) / d).st_mode)
            if mode != 0o755:
                wrong.append((f"{root}/{d}", oct(mode)))
        for f in files:
            st = os.lstat(Path(root) / f)
            if stat.S_ISREG(st.st_mode) and stat.S_IMODE(st.st_mode) != 0o644:
                wrong.append((f"{root}/{f}", oct(stat.S_IMODE(st.st_mode))))
    assert not wrong, wrong[:5]


# ------------------------------------------------------------------ finding 6: damaged images


def _truncate(path: Path) -> None:
    data = path.read_bytes()
    if path.is_symlink():
        path.unlink()
    path.write_bytes(data[: len(data) // 2])


def test_a_half_truncated_jpeg_fails_its_log(av2_fixture_log: Path, av2_fixture_calibration: Path,
                                             tmp_path: Path):
    log_dir = imaged_copy(av2_fixture_log, av2_fixture_calibration, tmp_path / "src" / "val", FIXTURE_ID)
    bad = sorted((log_dir / "sensors" / "cameras" / "ring_front_left").iterdir())[0]
    _truncate(bad)
    out = tmp_path / "out"
    code, _, err = cli("convert", "av2", log_dir.parent, out, "--no-progress")
    assert code == 2 and "no log converted" in err
    (failure,) = json.loads((out / "convert_report.json").read_text())["failed"]
    assert str(bad) in failure["error"] and "does not decode" in failure["error"]
    assert not (out / VERSION).exists()


def test_validate_decode_images_finds_a_truncated_image(native_synth_db: Path, tmp_path: Path):
    db = tmp_path / "db"
    shutil.copytree(native_synth_db, db, symlinks=True)
    sd = next(r for r in table(db, "sample_data") if r["filename"].endswith(".jpg"))
    _truncate(db / sd["filename"])
    code, out, _ = cli("validate", db, "--version", VERSION, "--quiet")
    assert code == 0  # the header alone is intact
    code, out, _ = cli("validate", db, "--version", VERSION, "--quiet", "--decode-images")
    assert code == 1 and sd["filename"] in out and "does not decode" in out


# ------------------------------------------------------------------ findings 8, 12, 13: bad input


def _one_line_error(code: int, err: str, *names: str) -> None:
    lines = err.strip().splitlines()
    assert code == 2, err
    assert len(lines) == 1 and lines[0].startswith("nuav2 ") and "Traceback" not in err, err
    for name in names:
        assert name in lines[0], (name, lines[0])


@pytest.fixture(scope="module")
def a_file(tmp_path_factory) -> Path:
    f = tmp_path_factory.mktemp("plain") / "not_a_dir"
    f.write_text("x")
    return f


@pytest.mark.parametrize("out, words", [
    ("{file}", ["{file}", "not a directory"]),
    ("{file}/out", ["{file}/out", "cannot create"]),
    ("/proc/nuav2_out", ["/proc/nuav2_out", "cannot create"]),
    ("/proc", ["/proc", "cannot write"]),
])
def test_convert_with_a_bad_out_is_one_line(out: str, words: list[str], a_file: Path, synth_log: Path):
    out = out.format(file=a_file)
    code, _, err = cli("convert", "av2", synth_log.parent, out, "--no-progress")
    _one_line_error(code, err, *[w.format(file=a_file) for w in words])


def test_a_read_only_out_is_one_line(synth_log: Path, tmp_path: Path):
    out = tmp_path / "ro"
    out.mkdir()
    out.chmod(0o555)
    try:
        code, _, err = cli_bound_by_modes("convert", "av2", synth_log.parent, out, "--no-progress")
        _one_line_error(code, err, str(out), "cannot write")
        assert not (out / "convert_report.json").exists()
    finally:
        out.chmod(0o755)


def test_a_missing_src_leaves_no_out_behind(tmp_path: Path):
    code, _, err = cli("convert", "av2", tmp_path / "missing", tmp_path / "out", "--no-progress")
    _one_line_error(code, err, str(tmp_path / "missing"))
    assert not (tmp_path / "out").exists()


def test_verbose_shows_the_traceback(a_file: Path, synth_log: Path):
    code, _, err = cli("-v", "convert", "av2", synth_log.parent, a_file, "--no-progress")
    assert code == 2 and "Traceback" in err and err.strip().splitlines()[-1].startswith("nuav2 convert:")


@pytest.mark.parametrize("flags, named", [
    (["--rig", "nuscenes"], "--rig"),
    (["--rig", "/no/such/rig.json"], "--rig"),
    (["--scale", "0.5"], "--scale"),
    (["--recon-preset", "fast"], "--recon-preset"),
    (["--mode", "warp", "--image-link", "symlink"], "--image-link"),
])
def test_flags_of_other_modes_are_errors(flags: list[str], named: str, synth_log: Path, tmp_path: Path):
    code, _, err = cli("convert", "av2", synth_log.parent, tmp_path / "out", "--no-progress", *flags)
    _one_line_error(code, err, named, "--mode")
    assert not (tmp_path / "out").exists()


def test_reader_errors_name_the_flags(av2_fixture_log: Path, av2_fixture_calibration: Path, tmp_path: Path):
    """No calibration: says --calibration (not calibration_dir); no cameras: says --allow-missing-cameras."""
    from test_writer_support import link_log

    src = tmp_path / "src" / "train"
    link_log(av2_fixture_log, src, FIXTURE_ID)
    code, _, err = cli("convert", "av2", src, tmp_path / "o1", "--no-progress")
    assert code == 2
    (failure,) = json.loads((tmp_path / "o1" / "convert_report.json").read_text())["failed"]
    assert "--calibration" in failure["error"] and "calibration_dir" not in failure["error"]
    code, _, err = cli("convert", "av2", src, tmp_path / "o2", "--calibration", av2_fixture_calibration,
                       "--no-progress")
    (failure,) = json.loads((tmp_path / "o2" / "convert_report.json").read_text())["failed"]
    assert code == 2 and "--allow-missing-cameras" in failure["error"]
    code, _, err = cli("convert", "av2", src, tmp_path / "o3", "--calibration", tmp_path / "nope",
                       "--no-progress")
    _one_line_error(code, err, "--calibration")


def test_logged_counts_match_what_is_written(synth_log: Path, tmp_path: Path, caplog):
    """A camera missing with --allow-missing-cameras: no "skipped N of N sweeps" before writing N samples."""
    src = tmp_path / "src" / "train"
    shutil.copytree(synth_log, src / synth_log.name)
    shutil.rmtree(src / synth_log.name / "sensors" / "cameras" / "ring_rear_left")
    caplog.set_level("INFO")
    summary = convert(src, tmp_path / "out", "--allow-missing-cameras")
    n_sweeps = len(list((synth_log / "sensors" / "lidar").iterdir()))
    assert summary["samples"] == n_sweeps
    assert "skipped" not in caplog.text and "0 of" not in caplog.text
    assert f"{n_sweeps} samples from {n_sweeps} sweeps, 6 cameras" in caplog.text


@pytest.mark.parametrize("argv, named", [
    (["eval", "{pred}", "--dataroot", "{db}", "--version", VERSION, "--split", "nope"],
     ["--split nope", "all"]),
    (["eval", "{bad_json}", "--dataroot", "{db}", "--version", VERSION],
     ["{bad_json}", "not valid JSON"]),
    (["eval", "{pred}", "--dataroot", "{db}", "--version", "v9"], ["--version v9", VERSION]),
    (["viz", "{db}", "--version", VERSION, "--sample", "f" * 32, "--out", "{tmp}/x.png"],
     ["--sample", "f" * 32]),
    (["infos", "{db}", "--version", "v9", "--out", "{tmp}"], ["--version v9", VERSION]),
    (["split", "{db}", "--version", "v9"], ["--version v9"]),
    (["split", "{tmp}/missing", "--version", VERSION], ["{tmp}/missing"]),
    (["inspect", "{tmp}/missing"], ["{tmp}/missing"]),
])
def test_every_command_answers_bad_input_in_one_line(argv, named, native_synth_db: Path, tmp_path: Path):
    pred, bad_json = tmp_path / "pred.json", tmp_path / "bad.json"
    pred.write_text(json.dumps({"meta": {}, "results": []}))
    bad_json.write_text("{not json")
    fill = {"db": native_synth_db, "pred": pred, "bad_json": bad_json, "tmp": tmp_path}
    code, _, err = cli(*[a.format(**fill) for a in argv])
    _one_line_error(code, err, *[n.format(**fill) for n in named])


def test_atomic_writes_follow_the_umask(tmp_path: Path):
    """The atomic writers themselves: umask 022 -> 0644 / 0755; umask 077 -> 0600 / 0700 (the user's)."""
    from nuav2.atomic import atomic_directory, atomic_write_bytes

    for mask, file_mode, dir_mode in ((0o022, 0o644, 0o755), (0o077, 0o600, 0o700), (0o002, 0o664, 0o775)):
        with umask(mask):
            atomic_write_bytes(tmp_path / f"f{mask}", b"x")
            with atomic_directory(tmp_path / f"d{mask}") as d:
                (d / "x").write_text("x")
        assert stat.S_IMODE((tmp_path / f"f{mask}").stat().st_mode) == file_mode
        assert stat.S_IMODE((tmp_path / f"d{mask}").stat().st_mode) == dir_mode


def test_error_lines_name_the_file_and_flag_internal_errors():
    from nuav2.cli import describe_error

    assert describe_error(FileNotFoundError(2, "No such file or directory", "/x/y")) == \
        "/x/y: No such file or directory"
    assert describe_error(AssertionError("Database version not found: /d/v9")) == \
        "Database version not found: /d/v9"
    line = describe_error(RuntimeError("boom\n  at depth"))
    assert line.startswith("internal error: RuntimeError: boom at depth") and "nuav2 -v" in line
