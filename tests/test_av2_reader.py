"""converters.av2 on the real AV2 fixture, checked against av2's own readers, plus bad-input cases.

The error cases build a log in tmp_path out of symlinks to the fixture files and replace only
the file they break, so every case is the real log with one thing wrong.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.feather as feather
import pytest
from av2.geometry.camera.pinhole_camera import PinholeCamera
from av2.geometry.geometry import quat_to_mat
from av2.utils.io import read_city_SE3_ego, read_lidar_sweep

from converters.av2 import AV2LogError, find_logs, read_log, synced_sweeps
from converters.av2.calibration import rig_from_calibration
from nuav2.geometry import quat_to_rot
from nuav2.rig import load_rig

SWEEP_TS = 315973157959879000
MS = 1_000_000


@pytest.fixture(scope="module")
def scene(av2_fixture_log, av2_fixture_calibration):
    return read_log(av2_fixture_log, av2_fixture_calibration, require_cameras=False)


def make_log(dst: Path, src_log: Path, calibration: Path | None = None, copy: tuple[str, ...] = ()) -> Path:
    """A log dir of per-file symlinks to ``src_log``; files named in ``copy`` are real copies to mutate."""
    for f in src_log.rglob("*"):
        if f.is_file():
            rel = f.relative_to(src_log)
            (dst / rel).parent.mkdir(parents=True, exist_ok=True)
            if str(rel) in copy:
                shutil.copyfile(f, dst / rel)
            else:
                os.symlink(f, dst / rel)
    if calibration is not None:
        (dst / "calibration").mkdir()
        for f in calibration.iterdir():
            if str(Path("calibration") / f.name) in copy:
                shutil.copyfile(f, dst / "calibration" / f.name)
            else:
                os.symlink(f, dst / "calibration" / f.name)
    return dst


@pytest.fixture
def tmp_log(tmp_path, av2_fixture_log, av2_fixture_calibration):
    """Factory: a symlinked copy of the fixture log with its own calibration/ dir."""
    def build(*copy: str, name: str = "adcf7d18-0510-35b0-a2fa-b4cea13a6d76", parent: str = "logs") -> Path:
        return make_log(tmp_path / parent / name, av2_fixture_log, av2_fixture_calibration, copy)
    return build


# --- the real fixture -------------------------------------------------------------------------

def test_poses_match_av2_reader(scene, av2_fixture_log):
    # The file holds 2,637 rows with 2,637 distinct timestamps (the closest two are 2 ns apart),
    # so deduplication removes nothing here.
    assert len(scene.pose_timestamps_ns) == 2637
    assert np.all(np.diff(scene.pose_timestamps_ns) > 0)
    assert np.all(np.isfinite(scene.city_T_ego))
    oracle = read_city_SE3_ego(av2_fixture_log)
    assert sorted(oracle) == scene.pose_timestamps_ns.tolist()
    for i in range(0, 2637, 97):
        assert np.allclose(scene.city_T_ego[i], oracle[int(scene.pose_timestamps_ns[i])].transform_matrix,
                           rtol=0, atol=1e-9)


def test_city_T_ego_at_interpolates_between_rows(scene):
    ts = scene.pose_timestamps_ns
    assert np.allclose(scene.city_T_ego_at(ts[100:105]), scene.city_T_ego[100:105], atol=1e-9)
    mid = (ts[100] + ts[101]) // 2
    w = (mid - ts[100]) / (ts[101] - ts[100])
    expected_t = (1 - w) * scene.city_T_ego[100, :3, 3] + w * scene.city_T_ego[101, :3, 3]
    assert np.allclose(scene.city_T_ego_at(mid)[:3, 3], expected_t, rtol=0, atol=1e-9)
    with pytest.raises(ValueError, match="outside the pose table"):
        scene.city_T_ego_at(ts[0] - 1)


def test_sweep_loads_as_float64_like_av2(scene):
    assert [s.timestamp_ns for s in scene.lidar_sweeps] == [SWEEP_TS]
    ref = scene.lidar_sweeps[0]
    pts = scene.sweep(ref)
    assert pts.xyz_ego.shape == (100_660, 3) and pts.xyz_ego.dtype == np.float64
    assert pts.intensity.dtype == np.float32 and pts.laser_number.dtype == np.uint8
    assert np.array_equal(pts.xyz_ego, read_lidar_sweep(ref.path, "xyz").astype(np.float64))
    raw = feather.read_table(ref.path)
    assert np.array_equal(pts.intensity, raw.column("intensity").to_numpy().astype(np.float32))
    assert pts.laser_number.max() == 63 and pts.laser_number.min() == 0


def test_annotations_keep_track_ids(scene, av2_fixture_log):
    ann = scene.annotations
    assert len(ann) == 12_078
    assert len(set(ann.track_id)) == 146
    assert len(np.unique(ann.timestamp_ns)) == 156
    raw = feather.read_table(av2_fixture_log / "annotations.feather").to_pandas()
    assert list(ann.track_id) == raw["track_uuid"].tolist()
    assert list(ann.category) == raw["category"].tolist()
    assert np.array_equal(ann.size_lwh, raw[["length_m", "width_m", "height_m"]].to_numpy())
    assert np.array_equal(ann.ego_t_box, raw[["tx_m", "ty_m", "tz_m"]].to_numpy())
    assert np.allclose(quat_to_rot(ann.ego_q_box), quat_to_mat(raw[["qw", "qx", "qy", "qz"]].to_numpy()),
                       atol=1e-12)
    assert np.array_equal(ann.num_interior_pts, raw["num_interior_pts"].to_numpy())
    assert len(ann.at(SWEEP_TS)) == int((raw["timestamp_ns"] == SWEEP_TS).sum()) > 0


def test_rig_from_calibration_matches_av2_cameras(scene, tmp_log):
    log_dir = tmp_log()
    rig = scene.rig
    template = load_rig("av2")
    assert rig.origin_height_m == pytest.approx(0.32)
    assert rig.keyframe_lidar == "LIDAR_TOP"
    assert [lid.channel for lid in rig.lidars] == ["up_lidar", "down_lidar", "LIDAR_TOP"]
    lidar_top = rig.lidar("LIDAR_TOP").ego_T_lidar
    assert np.allclose(lidar_top, template.lidar("LIDAR_TOP").ego_T_lidar, atol=1e-12)
    assert rig.camera_channels[0] == "ring_front_center" and len(rig.cameras) == 9
    rng = np.random.default_rng(0)
    p_ego = np.column_stack([rng.uniform(-30, 30, 200), rng.uniform(-30, 30, 200), rng.uniform(-1, 3, 200)])
    for cam in rig.cameras:
        oracle = PinholeCamera.from_feather(log_dir, cam.channel)
        assert (cam.width, cam.height) == (oracle.width_px, oracle.height_px)
        assert np.allclose(cam.K, oracle.intrinsics.K, rtol=0, atol=1e-9)
        assert np.allclose(cam.ego_T_cam, oracle.ego_SE3_cam.transform_matrix, rtol=0, atol=1e-9)
        # Our projection (K @ cam_T_ego) equals av2's for points in front of the camera.
        uv_av2, p_cam, ok = oracle.project_ego_to_img(p_ego)
        p_cam_ours = (np.linalg.inv(cam.ego_T_cam) @ np.column_stack([p_ego, np.ones(200)]).T).T[:, :3]
        front = p_cam_ours[:, 2] > 0.5
        uvw = p_cam_ours[front] @ cam.K.T
        assert np.allclose(uvw[:, :2] / uvw[:, 2:], uv_av2[front, :2], atol=1e-6)
        for ours, theirs in zip(cam.ego_mask_polygons, template.camera(cam.channel).ego_mask_polygons):
            assert np.allclose(ours, theirs)
    assert len(rig.camera("ring_front_center").ego_mask_polygons) == 1


def test_rig_channels_restrict_cameras(av2_fixture_calibration):
    rig = rig_from_calibration(av2_fixture_calibration, ["ring_side_left", "ring_front_center"])
    assert rig.camera_channels == ["ring_front_center", "ring_side_left"]
    with pytest.raises(AV2LogError, match="no intrinsics for requested camera"):
        rig_from_calibration(av2_fixture_calibration, ["CAM_FRONT"])


def test_city_map_and_ground(scene):
    assert scene.city == "PIT" and scene.city_frame == "PIT_city_57819"
    assert scene.source == "av2" and scene.log_id == "adcf7d18-0510-35b0-a2fa-b4cea13a6d76"
    vm = scene.vector_map
    assert vm is not None
    assert (len(vm.lane_segments), len(vm.ped_crossings), len(vm.drivable_areas)) == (199, 11, 8)
    assert scene.ground_height is not None and scene.ground_height.heights.shape == (715, 794)
    assert scene.camera_frames == {ch: [] for ch in scene.rig.camera_channels}


def test_log_with_own_calibration_and_split(tmp_log, scene):
    log_dir = tmp_log(parent="val")
    own = read_log(log_dir, require_cameras=False)
    assert own.split == "val"  # the split dir the log sits in wins
    assert scene.split == "train"  # outside a split dir: av2's published list names the log train
    assert read_log(tmp_log(name="not-an-av2-log-id"), require_cameras=False).split == ""
    assert np.array_equal(own.city_T_ego, scene.city_T_ego)
    assert all(np.array_equal(a.ego_T_cam, b.ego_T_cam) for a, b in zip(own.rig.cameras, scene.rig.cameras))


def test_find_logs(tmp_path, tmp_log):
    a = tmp_log(name="log_a", parent="root/sensor/train")
    b = tmp_log(name="log_b", parent="root/sensor/val")
    c = tmp_log(name="log_c", parent="root/sensor/train")
    (tmp_path / "root/sensor/train/not_a_log").mkdir()
    # an interrupted atomic write of a log (killed synth run) holds the pose file but is no log
    tmp_log(name=".log_d.x1y2.partial", parent="root/sensor/train")
    assert find_logs(tmp_path / "root") == [a, c, b]
    assert find_logs(tmp_path / "root/sensor") == [a, c, b]
    assert find_logs(tmp_path / "root/sensor/train") == [a, c]
    assert find_logs(a) == [a]
    with pytest.raises(AV2LogError, match="no AV2 logs found") as err:
        find_logs(tmp_path / "root/sensor/train/not_a_log")
    assert "not_a_log" in str(err.value)
    with pytest.raises(AV2LogError, match="not a directory"):
        find_logs(tmp_path / "absent")


# --- bad input --------------------------------------------------------------------------------

def _rewrite(path: Path, edit) -> None:
    df = feather.read_table(path).to_pandas()
    df = edit(df)
    path.unlink()
    feather.write_feather(pa.Table.from_pandas(df, preserve_index=False), path)


@pytest.mark.parametrize("name", ["city_SE3_egovehicle.feather", "annotations.feather",
                                  "calibration/intrinsics.feather",
                                  "calibration/egovehicle_SE3_sensor.feather"])
def test_corrupt_feather_names_the_file(tmp_log, name):
    log_dir = tmp_log(name)
    (log_dir / name).write_bytes(b"ARROW1\x00\x00this is not a feather file")
    with pytest.raises(AV2LogError, match="unreadable feather") as err:
        read_log(log_dir, require_cameras=False)
    assert str(log_dir / name) in str(err.value)


def test_corrupt_sweep_names_the_file(tmp_log):
    name = f"sensors/lidar/{SWEEP_TS}.feather"
    log_dir = tmp_log(name)
    (log_dir / name).write_bytes(b"\x00" * 64)
    scene = read_log(log_dir, require_cameras=False)  # sweeps load lazily
    with pytest.raises(AV2LogError, match="unreadable feather") as err:
        scene.sweep(scene.lidar_sweeps[0])
    assert str(log_dir / name) in str(err.value)


def test_missing_column_names_file_and_column(tmp_log):
    log_dir = tmp_log("city_SE3_egovehicle.feather")
    _rewrite(log_dir / "city_SE3_egovehicle.feather", lambda df: df.drop(columns=["qz"]))
    with pytest.raises(AV2LogError, match=r"missing column\(s\) \['qz'\]") as err:
        read_log(log_dir, require_cameras=False)
    assert "city_SE3_egovehicle.feather" in str(err.value)


@pytest.mark.parametrize("as_null", [False, True])
def test_nan_pose_names_file_row_and_column(tmp_log, as_null):
    """A NaN float and a null (missing) entry are both refused, naming file, row and column."""
    path = tmp_log("city_SE3_egovehicle.feather") / "city_SE3_egovehicle.feather"
    table = feather.read_table(path)
    tx = table.column("tx_m").to_numpy().copy()
    tx[17] = np.nan
    col = pa.array(tx, from_pandas=as_null)  # from_pandas turns NaN into null
    assert col.null_count == int(as_null)
    feather.write_feather(table.set_column(table.column_names.index("tx_m"), "tx_m", col), path)
    with pytest.raises(AV2LogError, match="value (nan )?in column 'tx_m' at row 17") as err:
        read_log(path.parent, require_cameras=False)
    assert str(path) in str(err.value)


def test_duplicate_and_shuffled_poses_dedupe_deterministically(tmp_log, scene, caplog):
    log_dir = tmp_log("city_SE3_egovehicle.feather")

    def dup_and_shuffle(df):
        dup = df.iloc[[5, 5, 40]].copy()
        dup["tx_m"] += [0.0, 3.0, 0.0]  # one duplicate of row 5 disagrees; it comes after the original
        return pd.concat([df.sample(frac=1.0, random_state=0), dup], ignore_index=True)
    _rewrite(log_dir / "city_SE3_egovehicle.feather", dup_and_shuffle)
    with caplog.at_level(logging.WARNING):
        deduped = read_log(log_dir, require_cameras=False)
    assert np.array_equal(deduped.pose_timestamps_ns, scene.pose_timestamps_ns)
    assert np.array_equal(deduped.city_T_ego, scene.city_T_ego)  # first row of each timestamp kept
    assert "dropped 3 rows with a repeated timestamp (1 of them with a different pose)" in caplog.text


def test_bad_calibration_quaternion_names_file_and_sensor(tmp_log):
    name = "calibration/egovehicle_SE3_sensor.feather"
    log_dir = tmp_log(name)

    def skew(df):
        df.loc[df.sensor_name == "ring_side_left", "qw"] *= 1.5
        return df
    _rewrite(log_dir / name, skew)
    with pytest.raises(AV2LogError, match="sensor 'ring_side_left'.*non-unit quaternion") as err:
        read_log(log_dir, require_cameras=False)
    assert str(log_dir / name) in str(err.value)


def test_missing_stereo_intrinsics_leaves_stereo_out(tmp_log, caplog):
    """av2-api#274: one real log has no stereo intrinsics rows."""
    name = "calibration/intrinsics.feather"
    log_dir = tmp_log(name)
    _rewrite(log_dir / name, lambda df: df[~df.sensor_name.str.startswith("stereo")])
    with caplog.at_level(logging.WARNING):
        scene = read_log(log_dir, require_cameras=False)
    assert len(scene.rig.cameras) == 7 and not any(c.startswith("stereo") for c in scene.rig.camera_channels)
    assert "stereo_front_left" in caplog.text and "no intrinsics" in caplog.text


def test_missing_calibration_dir(av2_fixture_log):
    with pytest.raises(AV2LogError, match="calibration directory not found") as err:
        read_log(av2_fixture_log)
    assert str(av2_fixture_log / "calibration") in str(err.value)


def test_missing_camera_dir_when_required(tmp_log):
    log_dir = tmp_log()
    with pytest.raises(AV2LogError, match="directory not found for rig camera 'ring_front_center'") as err:
        read_log(log_dir)
    assert str(log_dir / "sensors/cameras/ring_front_center") in str(err.value)


def test_empty_camera_dir_when_required(tmp_log):
    log_dir = tmp_log()
    (log_dir / "sensors/cameras/ring_front_center").mkdir(parents=True)
    with pytest.raises(AV2LogError, match="no <timestamp_ns>.jpg images") as err:
        read_log(log_dir, channels=["ring_front_center"])
    assert str(log_dir / "sensors/cameras/ring_front_center") in str(err.value)


def test_missing_annotations_give_empty_boxes(tmp_log, caplog):
    log_dir = tmp_log(name="ffffffff-0510-35b0-a2fa-b4cea13a6d76")  # no split folder, not a published id
    (log_dir / "annotations.feather").unlink()
    with caplog.at_level(logging.INFO):
        scene = read_log(log_dir, require_cameras=False)
    assert len(scene.annotations) == 0 and scene.annotations.size_lwh.shape == (0, 3)
    assert "no annotations file" in caplog.text


@pytest.mark.parametrize("split", ["train", "val"])
def test_missing_annotations_in_a_labelled_split_fail_the_log(tmp_log, split):
    """A partial download must not put unlabelled scenes into a training set without a word."""
    log_dir = tmp_log(parent=split)
    (log_dir / "annotations.feather").unlink()
    with pytest.raises(AV2LogError, match=f"missing; every AV2 {split} log ships its boxes") as err:
        read_log(log_dir, require_cameras=False)
    assert str(log_dir / "annotations.feather") in str(err.value)
    test_dir = tmp_log(parent="test", name="ffffffff-0510-35b0-a2fa-b4cea13a6d76")
    (test_dir / "annotations.feather").unlink()
    assert len(read_log(test_dir, require_cameras=False).annotations) == 0


def test_missing_annotations_of_a_published_train_log_outside_its_split_folder_fail_the_log(tmp_log):
    """Found by review: the fixture (a published train log) copied out of train/ without its
    annotations converted as a 'train' scene with no boxes; the split came from av2's lists, the
    annotations rule from the folder name alone."""
    log_dir = tmp_log(parent="downloads")
    (log_dir / "annotations.feather").unlink()
    with pytest.raises(AV2LogError, match="missing; every AV2 train log ships its boxes"):
        read_log(log_dir, require_cameras=False)


def test_sweep_outside_pose_table_is_dropped(tmp_log, caplog):
    log_dir = tmp_log()
    early = log_dir / "sensors/lidar" / f"{SWEEP_TS - 1_000 * MS}.feather"
    os.symlink((log_dir / f"sensors/lidar/{SWEEP_TS}.feather").resolve(), early)
    with caplog.at_level(logging.WARNING):
        scene = read_log(log_dir, require_cameras=False)
    assert [s.timestamp_ns for s in scene.lidar_sweeps] == [SWEEP_TS]
    assert "dropped 1 of 2 lidar sweeps outside the pose table" in caplog.text


def test_nonfinite_lidar_points_are_dropped(tmp_log, caplog):
    name = f"sensors/lidar/{SWEEP_TS}.feather"
    log_dir = tmp_log(name)
    table = feather.read_table(log_dir / name)
    z = table.column("z").to_numpy().copy()
    z[[3, 99]] = np.nan
    table = table.set_column(table.column_names.index("z"), "z", pa.array(z))
    feather.write_feather(table, log_dir / name)
    scene = read_log(log_dir, require_cameras=False)
    with caplog.at_level(logging.WARNING):
        pts = scene.sweep(scene.lidar_sweeps[0])
    assert len(pts.xyz_ego) == 100_660 - 2 and np.all(np.isfinite(pts.xyz_ego))
    assert len(pts.intensity) == len(pts.laser_number) == len(pts.xyz_ego)
    assert "dropped 2 points with non-finite values" in caplog.text


def test_bad_map_archive_name(tmp_log):
    log_dir = tmp_log()
    archive = next((log_dir / "map").glob("log_map_archive_*.json"))
    archive.rename(archive.with_name("log_map_archive_whatever.json"))
    with pytest.raises(AV2LogError, match="does not end in ____<CITY>_city_<n>.json") as err:
        read_log(log_dir, require_cameras=False)
    assert "log_map_archive_whatever.json" in str(err.value)


# --- camera synchronisation -------------------------------------------------------------------

def _write_images(log_dir: Path, channel: str, timestamps: list[int]) -> None:
    ok, jpg = cv2.imencode(".jpg", np.full((4, 6, 3), 128, np.uint8))
    assert ok
    d = log_dir / "sensors/cameras" / channel
    d.mkdir(parents=True, exist_ok=True)
    for t in timestamps:
        (d / f"{t}.jpg").write_bytes(jpg.tobytes())


@pytest.fixture
def synced_log(tmp_log):
    """Three sweeps 100 ms apart; two 20 Hz cameras; ring_front_left lacks the image near sweep 2."""
    log_dir = tmp_log()
    src = (log_dir / f"sensors/lidar/{SWEEP_TS}.feather").resolve()
    for k in (1, 2):
        os.symlink(src, log_dir / "sensors/lidar" / f"{SWEEP_TS + k * 100 * MS}.feather")
    _write_images(log_dir, "ring_front_center", [SWEEP_TS + 10 * MS + k * 50 * MS for k in range(6)])
    left = [SWEEP_TS - 22_500_000 + k * 50 * MS for k in range(7)]
    left.remove(SWEEP_TS + 77_500_000)  # sweep 2 is then 27.5 ms from its nearest left image
    _write_images(log_dir, "ring_front_left", left)
    return log_dir


def test_synced_sweeps_skip_out_of_sync(synced_log, caplog):
    channels = ["ring_front_center", "ring_front_left"]
    scene = read_log(synced_log, channels=channels)
    assert scene.rig.camera_channels == channels
    assert len(scene.camera_frames["ring_front_center"]) == 6
    with caplog.at_level(logging.INFO):
        synced = synced_sweeps(scene, 25 * MS)
    assert [s.sweep.timestamp_ns for s in synced] == [SWEEP_TS, SWEEP_TS + 200 * MS]
    assert f"sweep {SWEEP_TS + 100 * MS}" in caplog.text and "ring_front_left (27.5 ms)" in caplog.text
    first = synced[0]
    assert first.frames["ring_front_center"].timestamp_ns == SWEEP_TS + 10 * MS
    assert first.frames["ring_front_left"].timestamp_ns == SWEEP_TS - 22_500_000
    assert first.max_offset_ns() == 22_500_000
    assert len(synced_sweeps(scene, 30 * MS)) == 3
    # Every camera frame has its own pose (interpolated at the image time).
    for f in scene.camera_frames["ring_front_left"]:
        assert np.all(np.isfinite(scene.city_T_ego_at(f.timestamp_ns)))


def test_no_synced_sweep_is_an_error_when_cameras_required(synced_log):
    with pytest.raises(AV2LogError, match="no lidar sweep has an image from every camera") as err:
        read_log(synced_log, channels=["ring_front_center", "ring_front_left"], camera_tolerance_ns=5 * MS)
    assert str(synced_log / "sensors/cameras") in str(err.value)


def test_camera_with_no_images_syncs_nothing(synced_log):
    scene = read_log(synced_log, channels=["ring_front_center", "ring_side_left"], require_cameras=False)
    assert scene.camera_frames["ring_side_left"] == []
    assert synced_sweeps(scene) == []
    assert len(synced_sweeps(scene, channels=["ring_front_center"])) == 3


# --- nuav2 inspect ----------------------------------------------------------------------------

def test_inspect_command_prints_summary(av2_fixture_log, av2_fixture_calibration, capsys):
    from nuav2.cli import main

    rc = main(["inspect", str(av2_fixture_log), "--calibration-dir", str(av2_fixture_calibration),
               "--allow-missing-cameras"])
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    assert out["city"] == "PIT" and out["poses"]["n"] == 2637 and out["lidar_sweeps"] == 1
    assert out["annotations"]["rows"] == 12_078 and out["annotations"]["tracks"] == 146
    assert out["vector_map"] == {"lane_segments": 199, "ped_crossings": 11, "drivable_areas": 8}
    assert out["ground_height"]["origin_height_m"]["mean"] == pytest.approx(0.32, abs=0.01)
    rc = main(["inspect", str(av2_fixture_log)])  # no calibration dir, cameras required
    assert rc == 2
    assert "calibration directory not found" in capsys.readouterr().err


def test_two_sweep_files_with_one_timestamp(tmp_log):
    log_dir = tmp_log()
    src = (log_dir / f"sensors/lidar/{SWEEP_TS}.feather").resolve()
    os.symlink(src, log_dir / f"sensors/lidar/0{SWEEP_TS}.feather")
    with pytest.raises(AV2LogError, match="name the same timestamp") as err:
        read_log(log_dir, require_cameras=False)
    assert str(log_dir / "sensors/lidar") in str(err.value)
