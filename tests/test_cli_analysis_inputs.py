"""Bad input to the analysis commands (``split``, ``infos``, ``eval``, ``viz``, ``inspect``,
``validate``) is one line naming the file or flag and what is wrong, exit 2, never an internal
error: flag values are refused while parsing, ``--out`` and ``--lists`` before any work or write,
malformed prediction records by file, sample token, vector index and field, and a damaged table
by its file. Every command runs on a real database made by ``nuav2 synth`` + ``nuav2 convert``."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from e2e_helpers import (
    GOOD_VECTOR,
    VERSION,
    cli,
    cli_bound_by_modes,
    copy_db,
    first_sample_token,
    results_file,
)

from nuav2.cli import main
from nuav2.evaluate import MAP_CLASSES

pytest_plugins = ["test_writer_support", "e2e_support"]


def _one_line(err: str) -> str:
    """The single stderr line of a refused command (logging lines of the work would be more)."""
    lines = [ln for ln in err.strip().splitlines() if not ln.startswith(("INFO", "WARNING"))]
    assert len(lines) == 1, err
    assert "internal error" not in lines[0] and "Traceback" not in err
    return lines[0]


def _refused(*argv: object) -> str:
    """Run ``nuav2 ARGV`` in this process, expect exit 2, return its one-line message."""
    code, _, err = cli(*argv)
    assert code == 2, err
    return _one_line(err)


def _refused_while_parsing(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    """argparse's exit 2 (before the command runs at all) and its one-line message."""
    with pytest.raises(SystemExit) as e:
        main([str(a) for a in argv])
    assert e.value.code == 2
    return _one_line(capsys.readouterr().err)


def _tables(db: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted((db / VERSION).iterdir())}


# ------------------------------------------------------------------ 1. split --lists naming no scene


def test_split_lists_naming_no_scene_are_refused_and_nothing_is_written(native_synth_db, tmp_path):
    db = copy_db(native_synth_db, tmp_path / "db")
    lists = tmp_path / "lists.json"
    lists.write_text(json.dumps({"train": ["scene-nope"], "val": [], "test": []}))
    before = _tables(db)
    msg = _refused("split", db, "--version", VERSION, "--lists", lists)
    assert str(lists) in msg and "scene-nope" in msg
    assert _tables(db) == before  # splits.json neither overwritten nor all-discarded


def test_split_lists_with_an_empty_train_list_says_so(native_synth_db, tmp_path, caplog):
    db = copy_db(native_synth_db, tmp_path / "db")
    (scene,) = [s["name"] for s in json.loads((db / VERSION / "scene.json").read_text())]
    lists = tmp_path / "lists.json"
    lists.write_text(json.dumps({"train": [], "val": [scene], "test": []}))
    code, _, err = cli("split", db, "--version", VERSION, "--lists", lists)
    assert code == 0, err
    empty = [r.getMessage() for r in caplog.records if "no scene in train and test" in r.getMessage()]
    assert len(empty) == 1 and f"--lists {lists}" in empty[0]


def test_split_lists_with_some_unknown_entries_still_split_and_say_so(native_synth_db, tmp_path, caplog):
    """Published lists name more logs than one database holds (the transfer benchmark's case)."""
    db = copy_db(native_synth_db, tmp_path / "db")
    (scene,) = [s["name"] for s in json.loads((db / VERSION / "scene.json").read_text())]
    lists = tmp_path / "lists.json"
    lists.write_text(json.dumps({"train": [scene, "scene-nope"], "val": [], "test": []}))
    code, out, err = cli("split", db, "--version", VERSION, "--lists", lists)
    assert code == 0, err
    assert json.loads(out)["new"]["unmatched_entries"] == ["scene-nope"]
    assert json.loads((db / VERSION / "splits.json").read_text())["geo_train"] == [scene]
    assert any("scene-nope" in r.getMessage() and str(lists) in r.getMessage() for r in caplog.records)
    # The empty holdouts are the lists' doing, not --min-distance's.
    empty = [r.getMessage() for r in caplog.records if "no scene in val and test" in r.getMessage()]
    assert len(empty) == 1 and f"--lists {lists}" in empty[0] and "--min-distance" not in empty[0]


def test_split_lists_with_a_bad_key_name_the_file(native_synth_db, tmp_path):
    db = copy_db(native_synth_db, tmp_path / "db")
    lists = tmp_path / "lists.json"
    lists.write_text(json.dumps({"holdout": ["scene-0001"]}))
    msg = _refused("split", db, "--version", VERSION, "--lists", lists)
    assert str(lists) in msg and "holdout" in msg


# ------------------------------------------------------------------ 2, 3, 7-11: flags refused while parsing


def _parse_cases(root: Path) -> list[tuple[list, str]]:
    """(argv, the flag its message must name) for every bounded flag of these commands."""
    db, v, out, pred = root / "db", VERSION, root / "out", root / "pred.json"
    infos = ["infos", db, "--version", v, "--out", out]
    split = ["split", db, "--version", v]
    evaluate = ["eval", pred, "--dataroot", db, "--version", v]
    viz = ["viz", db, "--version", v, "--sample", "tok", "--out", root / "v.png"]
    return [
        ([*infos, "--patch", "inf", "30"], "--patch"),
        ([*infos, "--patch", "60", "0"], "--patch"),
        ([*evaluate, "--patch", "inf", "30"], "--patch"),
        ([*evaluate, "--patch", "-60", "30"], "--patch"),
        ([*split, "--radius", "nan"], "--radius"),
        ([*split, "--radius", "-1"], "--radius"),
        ([*split, "--min-distance", "-5"], "--min-distance"),
        ([*split, "--min-distance", "inf"], "--min-distance"),
        ([*split, "--seed", "-1"], "--seed"),
        ([*split, "--ratios", "0.8", "nan", "0.1"], "--ratios"),
        ([*viz, "--tile-height", "0"], "--tile-height"),
        ([*viz, "--tile-height", "-5"], "--tile-height"),
        ([*viz, "--tile-height", "100000"], "--tile-height"),
        ([*viz, "--score-thr", "nan"], "--score-thr"),
        ([*viz, "--score-thr", "1.5"], "--score-thr"),
        (["inspect", root, "--tolerance-ms", "inf"], "--tolerance-ms"),
        (["inspect", root, "--tolerance-ms", "nan"], "--tolerance-ms"),
        (["inspect", root, "--tolerance-ms", "-1"], "--tolerance-ms"),
        ([*evaluate, "--n-resample", "1"], "--n-resample"),
        ([*evaluate, "--n-resample", "20000"], "--n-resample"),
        ([*evaluate, "--thresholds", "0.5", "0"], "--thresholds"),
        (["validate", db, "--version", v, "--max-per-kind", "-1"], "--max-per-kind"),
        ([*infos, "--workers", "0"], "--workers"),
        ([*infos, "--workers", "-3"], "--workers"),
        ([*infos, "--max-sweeps", "-1"], "--max-sweeps"),
    ]


_CASE_IDS = [f"{argv[0]} {flag} {' '.join(map(str, argv[argv.index(flag) + 1:]))}"
             for argv, flag in _parse_cases(Path("x"))]


@pytest.mark.parametrize("case", range(len(_CASE_IDS)), ids=_CASE_IDS)
def test_bad_flag_values_are_refused_while_parsing_naming_the_flag(case, tmp_path, capsys):
    argv, flag = _parse_cases(tmp_path)[case]
    msg = _refused_while_parsing(argv, capsys)
    assert f"argument {flag}:" in msg
    assert not (tmp_path / "out").exists() and not (tmp_path / "v.png").exists()


def test_viz_refuses_an_image_format_it_cannot_write_saying_which_it_can(tmp_path, capsys):
    msg = _refused_while_parsing(["viz", tmp_path, "--version", VERSION, "--sample", "tok",
                                  "--out", tmp_path / "v1.gif"], capsys)
    assert "argument --out:" in msg and "v1.gif" in msg and all(s in msg for s in (".png", ".jpg", ".jpeg"))


def test_viz_draws_at_the_smallest_tile_height_into_an_upper_case_jpeg(native_synth_db, tmp_path):
    import cv2

    out = tmp_path / "small.JPEG"
    token = first_sample_token(native_synth_db)
    code, _, err = cli("viz", native_synth_db, "--version", VERSION, "--sample", token, "--out", out,
                       "--tile-height", "16")
    assert code == 0, err
    img = cv2.imread(str(out))
    assert img is not None and img.shape[0] == 32  # two rows of camera tiles, 16 px each


# ------------------------------------------------------------------ 9. eval --classes


def test_eval_refuses_an_unknown_class_listing_the_known_ones(native_synth_db, tmp_path):
    pred = results_file(tmp_path / "pred.json", first_sample_token(native_synth_db), [GOOD_VECTOR])
    msg = _refused("eval", pred, "--dataroot", native_synth_db, "--version", VERSION,
                   "--classes", "divider", "foo")
    assert "--classes" in msg and "foo" in msg and all(c in msg for c in MAP_CLASSES)
    msg = _refused("eval", pred, "--dataroot", native_synth_db, "--version", VERSION,
                   "--classes", "divider", "divider")
    assert "--classes" in msg and "divider" in msg


def test_eval_against_a_gt_file_knows_the_file_s_classes(tmp_path):
    gt = tmp_path / "gt.json"
    gt.write_text(json.dumps({"GTs": [{"sample_token": "a", "vectors": [
        {"pts": GOOD_VECTOR["pts"], "cls_name": "stop_line"}]}]}))
    pred = results_file(tmp_path / "pred.json", "a", [{**GOOD_VECTOR, "cls_name": "stop_line"}])
    msg = _refused("eval", pred, "--gt-json", gt, "--classes", "stopline")
    assert "--classes" in msg and "stopline" in msg and "stop_line" in msg
    code, out, err = cli("eval", pred, "--gt-json", gt, "--classes", "stop_line", "--json")
    assert code == 0, err
    assert json.loads(out)["ap"]["stop_line"]["0.5"] == pytest.approx(1.0)


# ------------------------------------------------------------------ 4. malformed prediction records

BAD_RECORDS = {
    "cls_name": {**GOOD_VECTOR, "cls_name": ["divider"]},
    "confidence_level": {**GOOD_VECTOR, "confidence_level": None},
    "confidence_level ": {**GOOD_VECTOR, "confidence_level": "high"},
    "pts": {**GOOD_VECTOR, "pts": "abc"},
    "pts ": {**GOOD_VECTOR, "pts": [[1.0, 2.0], [3.0]]},
    "pts  ": {**GOOD_VECTOR, "pts": [[1.0, "x"], [2.0, 3.0]]},
    "pts   ": {**GOOD_VECTOR, "pts": [[1.0, None], [2.0, 3.0]]},
}


@pytest.mark.parametrize("command", ["eval", "viz"])
@pytest.mark.parametrize("field", list(BAD_RECORDS))
def test_a_malformed_prediction_names_file_sample_vector_and_field(native_synth_db, tmp_path, command, field):
    token = first_sample_token(native_synth_db)
    pred = results_file(tmp_path / "pred.json", token, [GOOD_VECTOR, BAD_RECORDS[field]])
    if command == "eval":
        msg = _refused("eval", pred, "--dataroot", native_synth_db, "--version", VERSION)
    else:
        msg = _refused("viz", native_synth_db, "--version", VERSION, "--sample", token,
                       "--out", tmp_path / "v.png", "--pred", pred)
        assert not (tmp_path / "v.png").exists()
    assert str(pred) in msg and token in msg and "vector 1" in msg and f"'{field.strip()}'" in msg


@pytest.mark.parametrize("command", ["eval", "viz"])
def test_a_prediction_file_that_is_not_utf8_is_named(native_synth_db, tmp_path, command):
    token = first_sample_token(native_synth_db)
    pred = tmp_path / "latin1.json"
    pred.write_bytes(json.dumps({"results": {token: []}, "meta": {"by": "_"}}).replace("_", "\xe9")
                     .encode("latin-1"))
    if command == "eval":
        msg = _refused("eval", pred, "--dataroot", native_synth_db, "--version", VERSION)
    else:
        msg = _refused("viz", native_synth_db, "--version", VERSION, "--sample", token,
                       "--out", tmp_path / "v.png", "--pred", pred)
    assert str(pred) in msg and "UTF-8" in msg


# ------------------------------------------------------------------ 5. damaged tables


def _truncate(text: str) -> str:
    return text[:97]


def _as_object(text: str) -> str:
    return json.dumps({"records": json.loads(text)})


def _int_token(text: str) -> str:
    records = json.loads(text)
    records[0]["token"] = 5
    return json.dumps(records)


DAMAGE = {"truncated": (_truncate, "cannot parse"), "object": (_as_object, "dict"),
          "wrong_type": (_int_token, "token")}


def _command(name: str, db: Path, tmp_path: Path) -> list:
    token = json.loads((db / VERSION / "scene.json").read_text())[0]["first_sample_token"]
    pred = results_file(tmp_path / "pred.json", token, [GOOD_VECTOR])
    return {"split": ["split", db, "--version", VERSION],
            "infos": ["infos", db, "--version", VERSION, "--out", tmp_path / "infos", "--no-progress"],
            "eval": ["eval", pred, "--dataroot", db, "--version", VERSION],
            "viz": ["viz", db, "--version", VERSION, "--sample", token, "--out", tmp_path / "v.png"]}[name]


@pytest.mark.parametrize("damage", list(DAMAGE))
@pytest.mark.parametrize("command", ["split", "infos", "eval", "viz"])
def test_a_damaged_sample_table_is_named_with_what_is_wrong(native_synth_db, tmp_path, command, damage):
    db = copy_db(native_synth_db, tmp_path / "db")
    table = db / VERSION / "sample.json"
    rewrite, what = DAMAGE[damage]
    table.write_text(rewrite(table.read_text()))
    before = _tables(db)
    msg = _refused(*_command(command, db, tmp_path))
    assert str(table) in msg and what in msg
    assert _tables(db) == before and not (tmp_path / "infos").exists() and not (tmp_path / "v.png").exists()


# ------------------------------------------------------------------ 6. --out checked before the work


@pytest.mark.parametrize("command", ["eval", "viz"])
def test_an_unusable_out_is_refused_before_the_work_naming_the_given_path(native_synth_db, tmp_path, command):
    token = first_sample_token(native_synth_db)
    pred = results_file(tmp_path / "pred.json", token, [GOOD_VECTOR])
    folder = tmp_path / "emptydir.png"
    folder.mkdir()
    (tmp_path / "afile").write_text("x")
    for out, why in ((folder, "folder"), (tmp_path / "afile" / "x.png", "not a folder")):
        if command == "eval":
            argv = ["eval", pred, "--dataroot", native_synth_db, "--version", VERSION, "--out", out]
        else:  # an unknown --sample would be found by the work: the --out check comes first
            argv = ["viz", native_synth_db, "--version", VERSION, "--sample", "nope", "--out", out]
        msg = _refused(*argv)
        assert msg.startswith(f"nuav2 {command}: --out {out}:") and why in msg and ".tmp" not in msg
    assert list(folder.iterdir()) == []


def test_an_out_in_a_read_only_folder_is_refused_before_the_work(native_synth_db, tmp_path):
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o555)
    pred = results_file(tmp_path / "pred.json", first_sample_token(native_synth_db), [GOOD_VECTOR])
    code, _, err = cli_bound_by_modes("eval", pred, "--dataroot", native_synth_db, "--version", VERSION,
                                      "--out", locked / "r.json")
    assert code == 2, err
    msg = _one_line(err)
    assert f"--out {locked / 'r.json'}" in msg and "cannot write" in msg
    assert list(locked.iterdir()) == []


def test_eval_out_into_a_new_folder_still_works(native_synth_db, tmp_path):
    pred = results_file(tmp_path / "pred.json", first_sample_token(native_synth_db), [GOOD_VECTOR])
    out = tmp_path / "new" / "deeper" / "result.json"
    code, _, err = cli("eval", pred, "--dataroot", native_synth_db, "--version", VERSION, "--out", out)
    assert code == 0, err
    assert json.loads(out.read_text())["predictions"] == str(pred)


# ------------------------------------------------------------------ 12. validate into a closed pipe


def test_validate_into_a_closed_pipe_exits_quietly(native_synth_db):
    """``nuav2 validate ... | head -1``: the reader leaves early; no "Broken pipe" message."""
    read_end, write_end = os.pipe()
    os.close(read_end)  # the reader is gone before anything is written
    try:
        proc = subprocess.run([sys.executable, "-m", "nuav2", "validate", str(native_synth_db), "--version",
                               VERSION, "--no-files", "--json"], stdout=write_end, stderr=subprocess.PIPE,
                              timeout=300)
    finally:
        os.close(write_end)
    err = proc.stderr.decode()
    assert proc.returncode == 141 and "Broken pipe" not in err and "BrokenPipe" not in err, err


def test_split_straddle_without_regions_is_refused(native_synth_db, tmp_path):
    """Found by review: --straddle (a region-mode rule) was ignored without --regions."""
    db = copy_db(native_synth_db, tmp_path / "db")
    before = _tables(db)
    assert _refused("split", db, "--version", VERSION, "--straddle", "drop") == \
        "nuav2 split: --straddle applies to --regions only"
    assert _tables(db) == before


@pytest.mark.parametrize("damage", ["garbled", "no_offset"])
def test_validate_reports_a_log_placement_split_cannot_read(native_synth_db, tmp_path, damage):
    """Found by review: with nuav2_logs.json replaced by 'x', validate passed while split refused the
    database ("cannot read the per-log city placement")."""
    db = copy_db(native_synth_db, tmp_path / "db")
    logs_file = db / VERSION / "nuav2_logs.json"
    if damage == "garbled":
        logs_file.write_text("x")
    else:
        records = json.loads(logs_file.read_text())
        del records[0]["city_offset"]
        logs_file.write_text(json.dumps(records))
    code, out, _ = cli("validate", db, "--version", VERSION, "--no-files")
    placement = [ln for ln in out.splitlines() if "placement" in ln]
    assert code == 1 and len(placement) == 1 and str(logs_file) in placement[0], out
    why = "cannot read the per-log city placement" if damage == "garbled" else "'city_offset'"
    assert why in placement[0]
    assert str(logs_file) in _refused("split", db, "--version", VERSION)


def test_split_into_a_read_only_database_names_splits_json(native_synth_db, tmp_path):
    """Found by review: the message named the atomic writer's random '.splits.json.XXXX.tmp'."""
    db = copy_db(native_synth_db, tmp_path / "db")
    (db / VERSION).chmod(0o555)
    try:
        code, _, err = cli_bound_by_modes("split", db, "--version", VERSION)
    finally:
        (db / VERSION).chmod(0o755)
    assert code == 2, err
    msg = _one_line(err)
    assert f"{db / VERSION / 'splits.json'}: Permission denied" in msg and ".tmp" not in msg, msg


def test_viz_on_a_cut_short_camera_image_is_one_line_naming_it(native_synth_db, tmp_path):
    """Found by review: cv2.imread decoded a truncated JPEG with grey rows, libjpeg printing 'Premature
    end of JPEG file' on stderr (a second line, from C; the MapTR loader trained on the grey rows)."""
    db = copy_db(native_synth_db, tmp_path / "db")
    token = first_sample_token(db)
    rows = json.loads((db / VERSION / "sample_data.json").read_text())
    cam = next(r for r in rows
               if r["sample_token"] == token and r["is_key_frame"] and r["fileformat"] == "jpg")
    cut = db / "broken" / Path(cam["filename"]).name
    cut.parent.mkdir()
    data = (db / cam["filename"]).read_bytes()
    cut.write_bytes(data[: len(data) * 2 // 3])
    cam["filename"] = str(cut.relative_to(db))
    (db / VERSION / "sample_data.json").write_text(json.dumps(rows))
    proc = subprocess.run([sys.executable, "-m", "nuav2", "viz", str(db), "--version", VERSION,
                           "--sample", token, "--out", str(tmp_path / "v.png")],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1, proc.stderr
    assert f"{cut}: camera image cut short" in proc.stderr and not (tmp_path / "v.png").exists()
