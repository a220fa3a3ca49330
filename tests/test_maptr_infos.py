"""``nuav2 infos`` on a native AV2 conversion: the camera set and order MapTR expects (its per-camera
embeddings are indexed by position), ``--cameras``, ``--path-root`` kept as given, and a warning for
a database without cameras.

The database is a synthetic AV2 log with the two stereo cameras (as real AV2 logs have), converted by
``nuav2 convert`` (see ``test_maptr_infos_support``).
"""

from __future__ import annotations

import json
import logging
import pickle
import shutil
from pathlib import Path

import pytest
from e2e_helpers import VERSION, cli

from nuav2.maptr.infos import (
    AV2_RING_CAMERAS,
    MissingCameraError,
    camera_channels,
    default_cameras,
    info_filename,
)

pytest_plugins = ["test_maptr_infos_support"]

# MapTR's AV2 converter (tools/maptrv2/custom_av2_map_converter.py, CAM_NAMES), stereo commented out there.
MAPTR_AV2_CAMERAS = ["ring_front_center", "ring_front_right", "ring_front_left", "ring_rear_right",
                     "ring_rear_left", "ring_side_right", "ring_side_left"]
STEREO = ["stereo_front_left", "stereo_front_right"]


@pytest.fixture(scope="module")
def nusc(curved_db: Path):
    from nuscenes.nuscenes import NuScenes

    return NuScenes(VERSION, str(curved_db), verbose=False)


def _infos(db: Path, out: Path, *flags: object) -> list[dict]:
    argv = ["infos", db, "--version", VERSION, "--out", out, "--splits", "all", "--no-progress", *flags]
    code, _, err = cli(*argv)
    assert code == 0, err
    return pickle.loads((out / info_filename("nuav2", "all")).read_bytes())["infos"]


def _refused(*argv: object) -> str:
    code, _, err = cli(*argv)
    assert code == 2, err
    lines = [ln for ln in err.strip().splitlines() if not ln.startswith(("INFO", "WARNING"))]
    assert len(lines) == 1 and "internal error" not in lines[0], err
    return lines[0]


def test_native_av2_infos_hold_the_seven_ring_cameras_in_maptrs_order(curved_db: Path, nusc, tmp_path: Path):
    assert set(STEREO) <= set(nusc.sample[0]["data"])  # the log has the stereo pair, like real AV2
    assert list(AV2_RING_CAMERAS) == MAPTR_AV2_CAMERAS
    infos = _infos(curved_db, tmp_path)
    assert infos and all(list(info["cams"]) == MAPTR_AV2_CAMERAS for info in infos)


def test_dataset_uses_the_same_camera_default(curved_db: Path, nusc):
    from nuav2.maptr.dataset import MapSampleDataset

    ds = MapSampleDataset(curved_db, VERSION, "all", load_images=False, nusc=nusc)
    assert ds[0]["cam_names"] == MAPTR_AV2_CAMERAS and ds[0]["lidar2img"].shape == (7, 4, 4)


def test_other_rigs_get_every_camera_sorted_by_name(nusc, monkeypatch):
    # A sensor table without the whole ring: not AV2's rig any more.
    monkeypatch.setattr(nusc, "sensor", [s for s in nusc.sensor if s["channel"] != "ring_side_left"])
    expected = sorted(set(MAPTR_AV2_CAMERAS + STEREO) - {"ring_side_left"})
    assert default_cameras(nusc) == expected  # LIDAR_TOP (not a camera) left out


def test_a_keyframe_lacking_a_default_camera_is_refused_not_reordered(nusc):
    """The order is the database's, not each keyframe's: a keyframe without ring_side_left must not
    get the stereo pair and an alphabetical order (MapTR looks cameras up by position)."""
    sample = dict(nusc.sample[0])
    sample["data"] = {ch: tok for ch, tok in sample["data"].items() if ch != "ring_side_left"}
    with pytest.raises(MissingCameraError, match="ring_side_left") as e:
        camera_channels(nusc, sample)
    assert sample["token"] in str(e.value) and "--cameras" in str(e.value)


def test_infos_refuse_a_database_where_a_keyframe_lacks_a_camera(curved_db: Path, tmp_path: Path):
    db = tmp_path / "db"
    shutil.copytree(curved_db, db, symlinks=True)
    rows = json.loads((db / VERSION / "sample_data.json").read_text())
    cam = next(r for r in rows if r["is_key_frame"] and "/ring_side_left/" in r["filename"])
    cam["is_key_frame"] = False  # the devkit then lists no ring_side_left for that sample
    (db / VERSION / "sample_data.json").write_text(json.dumps(rows))
    msg = _refused("infos", db, "--version", VERSION, "--out", tmp_path / "out")
    assert cam["sample_token"] in msg and "ring_side_left" in msg
    assert not (tmp_path / "out").exists() or not list((tmp_path / "out").glob("*.pkl"))


def test_requested_cameras_missing_from_a_sample_are_an_error_naming_them(nusc):
    sample = dict(nusc.sample[0])
    sample["data"] = {ch: tok for ch, tok in sample["data"].items() if ch != "stereo_front_left"}
    with pytest.raises(MissingCameraError, match="stereo_front_left") as e:
        camera_channels(nusc, sample, ["ring_front_center", "stereo_front_left"])
    assert VERSION in str(e.value) and sample["token"] in str(e.value)


def test_cameras_flag_chooses_the_channels_and_their_order(curved_db: Path, tmp_path: Path):
    chosen = ["stereo_front_right", "ring_front_center", "stereo_front_left"]
    infos = _infos(curved_db, tmp_path, "--cameras", *chosen)
    assert all(list(info["cams"]) == chosen for info in infos)


@pytest.mark.parametrize(
    ("cameras", "named"),
    [
        (["ring_front_center", "CAM_FRONT", "ring_rear_lft"], ["CAM_FRONT", "ring_rear_lft"]),
        (["LIDAR_TOP"], ["LIDAR_TOP"]),  # a channel, but not a camera
        (["ring_front_center", "ring_front_center"], ["ring_front_center", "more than once"]),
    ],
)
def test_cameras_flag_refuses_unknown_channels_in_one_line(curved_db: Path, tmp_path: Path, cameras, named):
    msg = _refused("infos", curved_db, "--version", VERSION, "--out", tmp_path / "out", "--cameras", *cameras)
    assert "--cameras" in msg and all(n in msg for n in named)
    assert "ring_side_left" in msg or "more than once" in msg  # the cameras present are listed
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("root", ["./data/nuav2", "./data/nuav2/"])
def test_path_root_is_kept_exactly_as_given(curved_db: Path, tmp_path: Path, root: str):
    info = _infos(curved_db, tmp_path, "--path-root", root, "--max-sweeps", "2")[-1]
    paths = [info["lidar_path"], *(c["data_path"] for c in info["cams"].values()),
             *(s["data_path"] for s in info["sweeps"])]
    assert len(info["sweeps"]) == 2
    assert all(p.startswith(("./data/nuav2/samples/", "./data/nuav2/sweeps/")) for p in paths), paths
    assert not any("//" in p for p in paths)


def test_database_without_cameras_warns_once_naming_it(camera_less_db: Path, tmp_path: Path, caplog):
    with caplog.at_level(logging.WARNING):
        infos = _infos(camera_less_db, tmp_path)
    assert infos and all(info["cams"] == {} for info in infos)
    warnings = [r.getMessage() for r in caplog.records if "no camera" in r.getMessage()]
    assert len(warnings) == 1 and f"{camera_less_db}/{VERSION}" in warnings[0]
    assert f"{len(infos)} of {len(infos)} keyframes" in warnings[0]


@pytest.mark.parametrize("table, field", [("ego_pose", "translation"), ("calibrated_sensor", "translation"),
                                          ("calibrated_sensor", "camera_intrinsic")])
def test_infos_refuse_a_camera_record_with_nan(curved_db: Path, tmp_path: Path, table: str, field: str):
    """Found by review: a NaN in a keyframe camera's ego pose or calibration went into the .pkl (its
    sensor2lidar and lidar2img with it) and infos exited 0; only the LIDAR_TOP pose was checked."""
    db = tmp_path / "db"
    shutil.copytree(curved_db, db, symlinks=True)
    sample_data = json.loads((db / VERSION / "sample_data.json").read_text())
    cam = next(r for r in sample_data if r["is_key_frame"] and "/ring_front_center/" in r["filename"])
    key = {"ego_pose": "ego_pose_token", "calibrated_sensor": "calibrated_sensor_token"}[table]
    rows = json.loads((db / VERSION / f"{table}.json").read_text())
    row = next(r for r in rows if r["token"] == cam[key])
    if field == "camera_intrinsic":
        row[field][0][0] = float("nan")
    else:
        row[field][1] = float("nan")
    (db / VERSION / f"{table}.json").write_text(json.dumps(rows))  # json writes NaN, as a broken tool would
    msg = _refused("infos", db, "--version", VERSION, "--out", tmp_path / "out", "--no-progress")
    assert f"{table}.json: record {row['token']}" in msg and field in msg and "NaN or Inf" in msg, msg
    assert not (tmp_path / "out").exists() or not list((tmp_path / "out").glob("*.pkl"))


@pytest.mark.parametrize("flags, message", [
    (["--prefix", "../escaped"], "--prefix '../escaped': must be a file-name part"),
    (["--prefix", "a/b"], "--prefix 'a/b': must be a file-name part"),
    (["--prefix", ".."], "--prefix '..': must be a file-name part"),
    (["--ray-address", "auto"], "--ray-address applies to --executor ray only"),
])
def test_infos_flags_that_would_write_elsewhere_or_be_ignored(curved_db: Path, tmp_path: Path, flags,
                                                              message):
    """Found by review: --prefix ../escaped wrote every .pkl beside --out; --ray-address was ignored
    with the local executor (convert refuses it)."""
    out = tmp_path / "sub" / "out"
    assert message in _refused("infos", curved_db, "--version", VERSION, "--out", out, *flags)
    assert not (tmp_path / "sub").exists()


def test_infos_out_that_is_a_file_is_named_as_such(curved_db: Path, tmp_path: Path):
    out = tmp_path / "afile"
    out.write_text("x")
    assert _refused("infos", curved_db, "--version", VERSION, "--out", out) == f"nuav2 infos: --out {out}: " \
                                                                                "is not a folder"


def test_infos_refuse_a_split_without_scenes(curved_db: Path, tmp_path: Path):
    """Found by review: --splits geo_discarded (empty after nuav2 split) wrote a 0-sample .pkl, exit 0."""
    db = tmp_path / "db"
    shutil.copytree(curved_db, db, symlinks=True)
    code, _, err = cli("split", db, "--version", VERSION)
    assert code == 0, err
    assert json.loads((db / VERSION / "splits.json").read_text())["geo_val"] == []
    msg = _refused("infos", db, "--version", VERSION, "--out", tmp_path / "out", "--splits", "geo_train",
                   "geo_val")
    with_scenes = msg.split("splits with scenes:")[1]
    assert "split(s) geo_val hold no scenes in" in msg and "geo_train" in with_scenes
    assert "geo_val" not in with_scenes
    assert not (tmp_path / "out").exists() or not list((tmp_path / "out").iterdir())
