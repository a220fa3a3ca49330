"""Broken AV2 input the reader must refuse with one line naming the file (and column / row):
a repeated (track, timestamp) annotation, values of the wrong type, a zero box size, an unknown
category, and a correctly named camera image or sweep that is not a readable file.

Each case copies a tiny synthetic log (generated once per module, ~1.5 s) and breaks one file.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.feather as feather
import pytest
from e2e_helpers import cli, umask

from converters.av2 import AV2LogError
from converters.av2.annotations import read_annotations
from converters.av2.calibration import rig_from_calibration
from converters.av2.cameras import list_camera_frames
from converters.av2.lidar import list_sweeps, load_av2_sweep
from converters.av2.poses import read_pose_table
from nuav2.nuscenes_db.annotations import KeyBoxes, annotation_records
from nuav2.synth import SynthConfig, generate_log

TINY = SynthConfig(seconds=0.5, image_scale=1 / 16, lidar_azimuth_steps=256, n_parked=1, n_moving=2,
                   n_pedestrians=0, map_margin_m=25.0)
POSE = "city_SE3_egovehicle.feather"
ANN = "annotations.feather"
INTR = "calibration/intrinsics.feather"
CAM = "sensors/cameras/ring_front_center"


@pytest.fixture(scope="module")
def tiny_log(tmp_path_factory) -> Path:
    return generate_log(tmp_path_factory.mktemp("input_errors_synth"), seed=3, config=TINY)


@pytest.fixture
def log_copy(tiny_log: Path, tmp_path: Path):
    """Factory: a hard-linked copy of the tiny log (a file to break is rewritten, never edited in place)."""
    def build(name: str = tiny_log.name, split: Path = tmp_path / "src" / "train") -> Path:
        return Path(shutil.copytree(tiny_log, split / name, copy_function=os.link))
    return build


def _set_column(path: Path, name: str, values: list | np.ndarray, typ: pa.DataType | None = None) -> None:
    table = feather.read_table(path)
    col = pa.array(values, type=typ) if typ is not None else pa.array(values)
    table = table.set_column(table.column_names.index(name), name, col)
    path.unlink()  # hard-linked to the module's log
    feather.write_feather(table, path)


def _first_sweep(log_dir: Path) -> Path:
    return sorted((log_dir / "sensors/lidar").iterdir())[1]


def _junk(path: Path, column: str) -> None:
    """One value of ``column`` replaced by "abc" (the column becomes strings)."""
    values = [str(v) for v in feather.read_table(path).column(column).to_pylist()]
    values[2] = "abc"
    _set_column(path, column, values)


def _float_with_nan(path: Path, column: str) -> None:
    values = feather.read_table(path).column(column).to_numpy().astype(np.float64)
    values[1] = np.nan
    _set_column(path, column, values)


def _float(path: Path, column: str) -> None:
    values = feather.read_table(path).column(column).to_numpy().astype(np.float64)
    values[0] += 0.5
    _set_column(path, column, values)


def _read(log_dir: Path, rel: str) -> None:
    """Read the part of the log that ``rel`` belongs to, with the reader function for it."""
    if rel == POSE:
        read_pose_table(log_dir)
    elif rel == ANN:
        read_annotations(log_dir)
    elif rel.startswith("calibration/"):
        rig_from_calibration(log_dir / "calibration")
    else:
        (ref,) = [s for s in list_sweeps(log_dir) if s.path.name == Path(rel).name]
        load_av2_sweep(ref)


# --- 1. a repeated (track_uuid, timestamp_ns) row -------------------------------------------------

def _repeat_row(path: Path, row: int) -> None:
    table = feather.read_table(path)
    path.unlink()
    feather.write_feather(pa.concat_tables([table, table.slice(row, 1)]), path)


def test_repeated_track_timestamp_names_file_track_timestamp_and_rows(log_copy):
    log_dir = log_copy()
    table = feather.read_table(log_dir / ANN)
    n = table.num_rows
    _repeat_row(log_dir / ANN, 3)
    track, ts = table.column("track_uuid")[3].as_py(), table.column("timestamp_ns")[3].as_py()
    with pytest.raises(AV2LogError) as err:
        read_annotations(log_dir)
    msg = str(err.value)
    assert msg.startswith(f"{log_dir / ANN}: ")
    assert f"track '{track}' has two boxes at timestamp_ns {ts} (rows 3 and {n})" in msg


def test_annotation_records_refuse_two_boxes_of_one_track_at_one_sample():
    eye = np.broadcast_to(np.eye(4), (2, 4, 4)).copy()
    boxes = KeyBoxes(rows=np.array([7, 9]), sample_index=np.array([0, 0]),
                     track_id=np.array(["t", "t"], object), category=["vehicle.car"] * 2,
                     attribute=[None, None], global_T_box=eye, ego_T_box=eye, size_lwh=np.ones((2, 3)),
                     num_lidar_pts=np.zeros(2, np.int64), visible=np.full(2, np.nan))
    with pytest.raises(ValueError, match=r"log L: track 't' has two boxes \(annotation rows 7 and 9\) at "
                                         r"sample s0"):
        annotation_records("L", boxes, ["s0"])


def test_a_batch_fails_the_broken_logs_alone_and_reports_them(log_copy, tmp_path):
    """A repeated annotation row used to convert into a database that failed `nuav2 validate`."""
    good = log_copy()
    dup = log_copy("d0b1d0b1-0000-4000-8000-000000000001")
    _repeat_row(dup / ANN, 0)
    dangling = log_copy("da91da91-0000-4000-8000-000000000002")
    image = sorted((dangling / CAM).iterdir())[2]
    image.unlink()
    os.symlink("/nonexistent/x.jpg", image)
    out = tmp_path / "out"
    with umask(0o022):
        code, _, err = cli("convert", "av2", good.parent, out, "--mode", "native", "--no-progress")
    assert code == 1, err
    report = json.loads((out / "convert_report.json").read_text())
    assert report["converted"] == [good.name]
    failed = {f["log_id"]: f["error"] for f in report["failed"]}
    assert failed.keys() == {dup.name, dangling.name}
    assert f"{dup / ANN}: track " in failed[dup.name] and "rows 0 and " in failed[dup.name]
    assert f"{image}: not a readable file (dangling symlink" in failed[dangling.name]
    code, stdout, stderr = cli("validate", out, "--quiet")
    assert code == 0, stdout + stderr


# --- 2. values of the wrong type ------------------------------------------------------------------

@pytest.mark.parametrize(("rel", "column", "damage", "found", "expected"), [
    (POSE, "qw", _junk, "string", "an integer or floating type"),
    (POSE, "timestamp_ns", _junk, "string", "an integer type"),
    (POSE, "timestamp_ns", _float_with_nan, "double", "an integer type"),
    (POSE, "timestamp_ns", _float, "double", "an integer type"),  # was rounded silently
    (ANN, "length_m", _junk, "string", "an integer or floating type"),
    (ANN, "timestamp_ns", _float_with_nan, "double", "an integer type"),  # was accepted silently
    (INTR, "fx_px", _junk, "string", "an integer or floating type"),
    (INTR, "width_px", _float, "double", "an integer type"),  # was truncated silently
    ("sweep", "x", _junk, "string", "an integer or floating type"),
    ("sweep", "laser_number", _float_with_nan, "double", "an integer type"),
])
def test_a_column_of_the_wrong_type_names_file_column_and_type(log_copy, rel, column, damage, found,
                                                                expected):
    log_dir = log_copy()
    if rel == "sweep":
        rel = str(_first_sweep(log_dir).relative_to(log_dir))
    damage(log_dir / rel, column)
    with pytest.raises(AV2LogError) as err:
        _read(log_dir, rel)
    assert str(err.value) == f"{log_dir / rel}: column '{column}' has type {found}, expected {expected}"


# --- 3. zero box size, unknown category -----------------------------------------------------------

def test_a_zero_box_size_names_file_and_row(log_copy):
    log_dir = log_copy()
    width = feather.read_table(log_dir / ANN).column("width_m").to_numpy().copy()
    width[4] = 0.0
    _set_column(log_dir / ANN, "width_m", width)
    with pytest.raises(AV2LogError, match=r"box size \[[^]]*, 0\.0, [^]]*\] at row 4 is not positive") as err:
        read_annotations(log_dir)
    assert str(err.value).startswith(f"{log_dir / ANN}: ")


def test_an_unknown_category_names_file_and_row(log_copy):
    log_dir = log_copy()
    cats = feather.read_table(log_dir / ANN).column("category").to_pylist()
    cats[5] = cats[6] = "FLYING_SAUCER"
    _set_column(log_dir / ANN, "category", cats)
    with pytest.raises(AV2LogError) as err:
        read_annotations(log_dir)
    msg = str(err.value)
    assert msg.startswith(f"{log_dir / ANN}: unknown category 'FLYING_SAUCER' at row 5 ")
    assert "2 row(s) in all" in msg and "\n" not in msg


# --- 4. a correctly named image or sweep that is not a readable file ------------------------------

def _break(path: Path, how: str) -> None:
    path.unlink()
    if how == "dangling":
        os.symlink("/nonexistent/x", path)
    elif how == "loop":
        os.symlink(path.name, path)
    else:
        path.mkdir()


@pytest.mark.parametrize(("how", "reason"), [("dangling", "dangling symlink or symlink loop"),
                                             ("loop", "dangling symlink or symlink loop"),
                                             ("directory", "a directory")])
def test_an_unreadable_camera_image_names_the_file(log_copy, caplog, how, reason):
    log_dir = log_copy()
    image = sorted((log_dir / CAM).iterdir())[2]
    _break(image, how)
    with pytest.raises(AV2LogError) as err:
        list_camera_frames(log_dir, ["ring_front_center"], require_cameras=True)
    assert str(err.value) == f"{image}: not a readable file ({reason})"
    assert "not named <timestamp_ns>.jpg" not in caplog.text


@pytest.mark.parametrize(("how", "reason"), [("dangling", "dangling symlink or symlink loop"),
                                             ("directory", "a directory")])
def test_an_unreadable_sweep_names_the_file(log_copy, caplog, how, reason):
    log_dir = log_copy()
    sweep = _first_sweep(log_dir)
    _break(sweep, how)
    with pytest.raises(AV2LogError) as err:
        list_sweeps(log_dir)
    assert str(err.value) == f"{sweep}: not a readable file ({reason})"
    assert "not named <timestamp_ns>.feather" not in caplog.text
