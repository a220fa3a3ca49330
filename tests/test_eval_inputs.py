"""``nuav2 eval`` on inputs reviewers found mishandled, on real ``nuav2 convert`` output: a split
that exists but holds no scenes, [x, y, z] points, malformed files, and GT-file flags and classes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from e2e_helpers import VERSION, cli, copy_db

pytest_plugins = ["test_writer_support", "e2e_support"]


def test_eval_on_a_split_without_scenes_is_a_usage_error(native_synth_db: Path, tmp_path: Path):
    """One log: ``nuav2 split`` leaves geo_val empty; scoring it would print mAP 0 and exit 0."""
    db = copy_db(native_synth_db, tmp_path / "db")
    code, _, err = cli("split", db, "--version", VERSION)
    assert code == 0, err
    assert json.loads((db / VERSION / "splits.json").read_text())["geo_val"] == []
    pred = tmp_path / "empty.json"
    pred.write_text(json.dumps({"meta": {}, "results": []}))
    code, out, err = cli("eval", pred, "--dataroot", db, "--version", VERSION, "--split", "geo_val")
    assert code == 2 and out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "--split geo_val: holds no scenes in" in lines[0], err
    assert "geo_train" in lines[0]  # says which splits have scenes


def test_eval_scores_3d_points_on_xy_as_viz_draws_them(native_synth_db: Path, tmp_path: Path):
    """MapTR's 3-D result files: eval scores x, y (z dropped, as MapTR's 2-D evaluation) through the
    reader viz uses, so the file viz draws is scored, the same as its 2-D twin."""
    from nuav2.evaluate.vector_files import load_predictions
    from nuav2.maptr.vectorize import gt_vectors_for_split
    from nuav2.viz import load_predictions as viz_predictions

    gts = gt_vectors_for_split(native_synth_db, VERSION, "all")
    files = {}
    for dim in (2, 3):
        results = [{"sample_token": tok, "vectors": [
            {"pts": [[*xy, 1.7][:dim] for xy in np.asarray(p).tolist()], "pts_num": len(p), "cls_name": c,
             "confidence_level": 0.9} for c, p in vecs]} for tok, vecs in gts.items()]
        files[dim] = tmp_path / f"pred{dim}d.json"
        files[dim].write_text(json.dumps({"meta": {}, "results": results}))
    read2, read3 = load_predictions(files[2]), load_predictions(files[3])
    assert all(v[1].shape[1] == 2 for vecs in read3.values() for v in vecs)
    assert all(np.array_equal(a[1], b[1]) for t in read2 for a, b in zip(read2[t], read3[t]))
    viz3 = viz_predictions(files[3])
    assert all(np.array_equal(a[1], b[1]) for t in read3 for a, b in zip(read3[t], viz3[t]))
    scores = {}
    for dim, path in files.items():
        code, out, err = cli("eval", path, "--dataroot", native_synth_db, "--version", VERSION,
                             "--split", "all", "--json")
        assert code == 0, err
        scores[dim] = json.loads(out)
    assert scores[3]["mAP"] == pytest.approx(1.0, abs=1e-9)
    assert scores[3]["ap"] == scores[2]["ap"]


def _gt_and_pred_files(db: Path, tmp_path: Path, own_class: str | None = None) -> tuple[Path, Path]:
    """The converted database's map GT as a MapTR GT file and as perfect predictions; ``own_class``
    renames the centerlines, as a GT file of another MapTR variant would name its own class."""
    from nuav2.maptr.vectorize import gt_vectors_for_split

    gts = gt_vectors_for_split(db, VERSION, "all")

    def rows(score: bool) -> list:
        return [{"sample_token": tok, "vectors": [
            {"pts": np.asarray(p).tolist(), "cls_name": own_class if own_class and c == "centerline" else c,
             **({"confidence_level": 0.9} if score else {})} for c, p in vecs]} for tok, vecs in gts.items()]

    gt_file, pred_file = tmp_path / "gt.json", tmp_path / "pred.json"
    gt_file.write_text(json.dumps({"GTs": rows(False)}))
    pred_file.write_text(json.dumps({"meta": {}, "results": rows(True)}))
    return gt_file, pred_file


def test_malformed_prediction_files_get_one_line_naming_the_file(native_synth_db: Path, tmp_path: Path):
    """Found by review: deep nesting ended as 'internal error: RecursionError'; true/false among
    numbers were scored as 1/0; a token repeated in the dict form silently replaced the first copy
    (mAP 0.951, exit 0)."""
    _, pred = _gt_and_pred_files(native_synth_db, tmp_path)
    results = json.loads(pred.read_text())["results"]
    token, vectors = results[0]["sample_token"], results[0]["vectors"]
    mixed = [dict(vectors[0], pts=[[True, False], *vectors[0]["pts"][1:]])]
    cases = {
        "deep.json": ("[" * 100_000 + "]" * 100_000, "nested too deeply"),
        "bools.json": (json.dumps({"meta": {}, "results": [{"sample_token": token, "vectors": mixed}]}),
                       "point 0 holds True, not a number"),
        "twice.json": ('{"results": {' + f'"{token}": {json.dumps(vectors)}, "{token}": []' + "}}",
                       f"key '{token}' appears twice"),
    }
    for name, (text, message) in cases.items():
        path = tmp_path / name
        path.write_text(text)
        code, out, err = cli("eval", path, "--dataroot", native_synth_db, "--version", VERSION)
        lines = err.strip().splitlines()
        assert code == 2 and out == "" and len(lines) == 1, (name, err[-300:])
        assert str(path) in lines[0] and message in lines[0] and "internal error" not in lines[0], lines


def test_gt_file_flags_and_its_own_class(native_synth_db: Path, tmp_path: Path, caplog):
    """--gt-json used to ignore --split/--dataroot/--version/--patch without a word, and called a
    class the GT file holds (not a MapTR class) one that 'has no GT class'."""
    gt, pred = _gt_and_pred_files(native_synth_db, tmp_path, own_class="lane")
    code, out, err = cli("eval", pred, "--gt-json", gt, "--split", "nope", "--dataroot", native_synth_db)
    assert code == 2 and out == ""
    assert err.strip() == ("nuav2 eval: --gt-json: --dataroot, --split only apply to the map GT, not to a "
                           "GT file; leave them out"), err
    with caplog.at_level("WARNING"):
        code, out, err = cli("eval", pred, "--gt-json", gt, "--json")
    assert code == 0, err
    assert "no GT class" not in caplog.text and "['lane'] are not MapTR classes" in caplog.text, caplog.text
    result = json.loads(out)
    assert result["mAP"] == pytest.approx(1.0, abs=1e-9) and "lane" not in result["classes"]
    code, out, _ = cli("eval", pred, "--gt-json", gt, "--json", "--classes", "divider", "lane")
    assert code == 0 and json.loads(out)["ap"]["lane"]["1.0"] == pytest.approx(1.0, abs=1e-9)
