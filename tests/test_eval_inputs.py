"""``nuav2 eval`` on inputs the reviewer found mishandled, on real ``nuav2 convert`` output:
a split that exists but holds no scenes, and a prediction file with [x, y, z] points."""

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
