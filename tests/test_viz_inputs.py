"""``nuav2 viz`` on damaged input, on a real database (``nuav2 synth`` + ``nuav2 convert``): a broken
map expansion or a NaN calibration is one line naming the real file (and record and field); a
prediction with huge coordinates draws what is visible, never an internal error."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from e2e_helpers import VERSION, cli, copy_db, first_sample_token, results_file
from test_cli_analysis_inputs import _one_line

from nuav2.viz import bev_panel, clip_polyline

pytest_plugins = ["test_writer_support", "e2e_support"]


def _viz(db, out, *flags) -> tuple[int, str]:
    code, _, err = cli("viz", db, "--version", VERSION, "--sample", first_sample_token(db), "--out", out,
                       "--tile-height", "16", *flags)
    return code, err


def test_viz_names_the_broken_map_expansion_file_where_it_is(native_synth_db, tmp_path):
    db = copy_db(native_synth_db, tmp_path / "db")
    (db / "maps").unlink()
    shutil.copytree(native_synth_db / "maps", db / "maps")
    files = sorted((db / "maps" / "expansion").glob("*.json"))
    for f in files:
        f.write_text('{"version":\n')
    code, err = _viz(db, tmp_path / "v.png")
    msg = _one_line(err)
    assert code == 2
    named = [f for f in files if str(f) in msg]
    assert named and "cannot parse" in msg
    assert str(db / VERSION / "expansion") not in msg  # no made-up path under the table folder


def test_viz_names_table_record_and_field_of_a_nan_calibrated_sensor_rotation(native_synth_db, tmp_path):
    db = copy_db(native_synth_db, tmp_path / "db")
    table = db / VERSION / "calibrated_sensor.json"
    records = json.loads(table.read_text())
    records[0]["rotation"] = [float("nan"), 0.0, 0.0, 0.0]
    table.write_text(json.dumps(records))
    code, err = _viz(db, tmp_path / "v.png")
    msg = _one_line(err)
    assert code == 2
    assert str(table) in msg and records[0]["token"] in msg and "rotation" in msg
    assert not (tmp_path / "v.png").exists()


@pytest.mark.parametrize("coord", [1e20, 1e200, 1.7e308])
def test_viz_draws_a_prediction_with_huge_coordinates(native_synth_db, tmp_path, coord):
    token = first_sample_token(native_synth_db)
    vector = {"pts": [[coord, 0.0], [-coord, 1.0]], "pts_num": 2, "cls_name": "divider",
              "confidence_level": 0.9}
    pred = results_file(tmp_path / "pred.json", token, [vector])
    code, err = _viz(native_synth_db, tmp_path / "v.png", "--pred", pred)
    assert code == 0, err
    assert (tmp_path / "v.png").stat().st_size > 0


def test_clipping_keeps_the_visible_part_of_a_line_between_far_points_exactly():
    assert [p.tolist() for p in clip_polyline([[-1e20, -2e20], [1e20, 2e20]], (16.0, 31.0))] == [
        [[-15.5, -31.0], [15.5, 31.0]]]
    parts = clip_polyline([[-20, 0], [0, 0], [5, 5], [20, 0], [30, 0], [0, -1]], (10.0, 10.0))
    assert [p.tolist() for p in parts] == [[[-10, 0], [0, 0], [5, 5], [10, 10 / 3]], [[10, -2 / 3], [0, -1]]]
    inside = np.array([[0.0, -5.0], [1.0, 5.0]])
    assert np.array_equal(clip_polyline(inside, (10.0, 10.0))[0], inside)
    assert clip_polyline([[20, 20], [30, 30]], (10.0, 10.0)) == []


def test_bev_draws_a_diagonal_through_far_points_as_its_visible_part():
    far = bev_panel([("divider", np.array([[-1e20, -2e20], [1e20, 2e20]]))], [], height_px=240)
    near = bev_panel([("divider", np.array([[-16.0, -32.0], [16.0, 32.0]]))], [], height_px=240)
    assert np.array_equal(far, near)
