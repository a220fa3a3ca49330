"""Native conversion of the real AV2 fixture log, checked with the unmodified devkit and av2's own math."""

from __future__ import annotations

import json
from pathlib import Path

import matplotlib
import numpy as np
import pandas as pd
import pytest
from av2.geometry.camera.pinhole_camera import PinholeCamera
from av2.utils.io import read_city_SE3_ego, read_lidar_sweep
from nuscenes.nuscenes import NuScenes
from pyquaternion import Quaternion
from scipy.spatial import cKDTree
from test_writer_support import FIXTURE_SWEEP_NS

from nuav2.nuscenes_db.categories import AV2_TO_NUSCENES
from nuav2.nuscenes_db.lidar_top import read_pcd_bin
from nuav2.nuscenes_db.tokens import is_token
from nuav2.rig import load_rig

matplotlib.use("Agg")
pytest_plugins = ["test_writer_support"]  # the imaged_log and native_db fixtures
VERSION = "v1.0-nuav2"
RING = ["ring_front_center", "ring_front_left", "ring_front_right", "ring_side_left", "ring_side_right",
        "ring_rear_left", "ring_rear_right"]


@pytest.fixture(scope="module")
def nusc(native_db: Path) -> NuScenes:
    return NuScenes(VERSION, str(native_db), verbose=False)


def _table(db: Path, name: str):
    return json.loads((db / VERSION / f"{name}.json").read_text())


def _image_ns(nusc: NuScenes, sd: dict) -> int:
    """The AV2 capture time of a symlinked image: its source file is named <timestamp_ns>.jpg."""
    return int(Path(nusc.get_sample_data_path(sd["token"])).resolve().stem)


def _log_meta(db: Path) -> dict:
    return json.loads((db / VERSION / "nuav2_logs.json").read_text())[0]


def test_devkit_loads_and_queries(nusc: NuScenes, native_db: Path, tmp_path, capsys):
    assert len(nusc.scene) == 1 and nusc.scene[0]["name"] == "scene-2469"  # 2000 + index in av2 TRAIN
    assert nusc.scene[0]["description"] == "adcf7d18-0510-35b0-a2fa-b4cea13a6d76"
    assert nusc.log[0]["logfile"] == "adcf7d18-0510-35b0-a2fa-b4cea13a6d76"
    assert nusc.log[0]["location"] == "av2-pit-adcf7d18"
    sample = nusc.sample[0]
    assert sample["prev"] == sample["next"] == ""
    assert set(sample["data"]) == {"LIDAR_TOP", *RING, "stereo_front_left", "stereo_front_right"}
    lidar_sd = nusc.get("sample_data", sample["data"]["LIDAR_TOP"])
    assert sample["timestamp"] == lidar_sd["timestamp"] == FIXTURE_SWEEP_NS // 1000
    for table in ("sample", "sample_data", "ego_pose", "sample_annotation", "instance", "scene", "log"):
        assert all(is_token(r["token"]) for r in getattr(nusc, table))
    # Each camera: one key frame and one sweep 50 ms later, linked both ways.
    for ch in RING:
        key = nusc.get("sample_data", sample["data"][ch])
        assert key["is_key_frame"] and key["prev"] == "" and key["next"]
        sweep = nusc.get("sample_data", key["next"])
        assert not sweep["is_key_frame"] and sweep["prev"] == key["token"]
        assert sweep["filename"].startswith(f"sweeps/{ch}/") and key["filename"].startswith(f"samples/{ch}/")
        assert (native_db / sweep["filename"]).is_symlink()
    stamps = [sd["timestamp"] for sd in nusc.sample_data]
    assert len(set(stamps)) == len(stamps)  # unique µs across all channels

    path, boxes, _ = nusc.get_sample_data(lidar_sd["token"])
    assert Path(path).is_file() and len(boxes) == len(sample["anns"]) == 44  # 47 boxes minus 3 SIGN
    cam_path, cam_boxes, K = nusc.get_sample_data(sample["data"]["ring_front_center"])
    assert K.shape == (3, 3) and 0 < len(cam_boxes) < len(boxes)
    assert len(nusc.get_boxes(lidar_sd["token"])) == 44
    assert np.all(np.isnan(nusc.box_velocity(sample["anns"][0])))  # one sample: no neighbour to difference
    front = sample["data"]["ring_front_center"]
    pts, depth, im = nusc.explorer.map_pointcloud_to_image(lidar_sd["token"], front)
    assert pts.shape[1] > 1000 and im.size == (1550, 2048)
    nusc.list_scenes()
    assert "scene-2469" in capsys.readouterr().out
    nusc.render_sample_data(lidar_sd["token"], out_path=str(tmp_path / "lidar.png"), verbose=False)
    nusc.render_sample_data(sample["data"]["ring_front_left"], out_path=str(tmp_path / "cam.png"),
                            verbose=False)
    assert (tmp_path / "lidar.png").stat().st_size > 10_000 and (tmp_path / "cam.png").stat().st_size > 1_000
    splits = json.loads((native_db / VERSION / "splits.json").read_text())
    assert splits == {"av2_val": ["scene-2469"], "all": ["scene-2469"]}


def _devkit_chain_float64(points_lidar: np.ndarray, cs_l: dict, pose_l: dict, pose_c: dict,
                          cs_c: dict) -> np.ndarray:
    """map_pointcloud_to_image's steps with pyquaternion, kept in float64; returns (N, 3) camera points."""
    p = points_lidar.T.astype(np.float64)
    p = Quaternion(cs_l["rotation"]).rotation_matrix @ p + np.array(cs_l["translation"])[:, None]
    p = Quaternion(pose_l["rotation"]).rotation_matrix @ p + np.array(pose_l["translation"])[:, None]
    p = Quaternion(pose_c["rotation"]).rotation_matrix.T @ (p - np.array(pose_c["translation"])[:, None])
    p = Quaternion(cs_c["rotation"]).rotation_matrix.T @ (p - np.array(cs_c["translation"])[:, None])
    return p.T


def test_projection_matches_av2_pinhole_camera(nusc: NuScenes, imaged_log):
    """LiDAR points through our written ego_pose/calibrated_sensor chain land on av2's pixels (1e-6 px)."""
    log_dir, _ = imaged_log
    sweep_path = log_dir / "sensors" / "lidar" / f"{FIXTURE_SWEEP_NS}.feather"
    xyz_egoS = read_lidar_sweep(sweep_path, attrib_spec="xyz").astype(np.float64)
    city_SE3_ego = read_city_SE3_ego(log_dir)
    sample = nusc.sample[0]
    lidar_sd = nusc.get("sample_data", sample["data"]["LIDAR_TOP"])
    cs_l = nusc.get("calibrated_sensor", lidar_sd["calibrated_sensor_token"])
    pose_l = nusc.get("ego_pose", lidar_sd["ego_pose_token"])
    # Points in the written LIDAR_TOP frame, in float64: AV2 ego -> ground-level ego (origin 0.32 m lower).
    h = load_rig("av2").origin_height_m
    R_l = Quaternion(cs_l["rotation"]).rotation_matrix
    xyz_lidar = (xyz_egoS + [0.0, 0.0, h] - np.array(cs_l["translation"])) @ R_l
    checked = 0
    for ch in RING:
        cam_sd = nusc.get("sample_data", sample["data"][ch])
        for sd in (cam_sd, nusc.get("sample_data", cam_sd["next"])):
            cs_c = nusc.get("calibrated_sensor", sd["calibrated_sensor_token"])
            pose_c = nusc.get("ego_pose", sd["ego_pose_token"])
            cam_ts_ns = _image_ns(nusc, sd)
            pinhole = PinholeCamera.from_feather(log_dir, ch)
            uv_av2, pts_cam_av2, valid = pinhole.project_ego_to_img_motion_compensated(
                xyz_egoS, city_SE3_ego[cam_ts_ns], city_SE3_ego[FIXTURE_SWEEP_NS])
            pts_cam = _devkit_chain_float64(xyz_lidar, cs_l, pose_l, pose_c, cs_c)
            uv = (np.array(cs_c["camera_intrinsic"]) @ pts_cam.T).T
            uv = uv[:, :2] / uv[:, 2:3]
            assert valid.sum() > 500
            assert np.abs(pts_cam - pts_cam_av2[:, :3])[valid].max() < 1e-9
            assert np.abs(uv - uv_av2)[valid].max() < 1e-6
            checked += int(valid.sum())
    assert checked > 10_000


def test_devkit_float32_projection_agrees_to_a_tenth_of_a_millimetre(nusc: NuScenes, imaged_log):
    """The devkit's own map_pointcloud_to_image (float32 points) vs av2: within 0.1 mm of 3-D error."""
    log_dir, _ = imaged_log
    xyz_egoS = read_lidar_sweep(log_dir / "sensors" / "lidar" / f"{FIXTURE_SWEEP_NS}.feather",
                                attrib_spec="xyz").astype(np.float64)
    city_SE3_ego = read_city_SE3_ego(log_dir)
    sample = nusc.sample[0]
    for ch in ("ring_front_center", "ring_side_right"):
        sd = nusc.get("sample_data", sample["data"][ch])
        pinhole = PinholeCamera.from_feather(log_dir, ch)
        uv_av2, pts_cam_h, _ = pinhole.project_ego_to_img_motion_compensated(
            xyz_egoS, city_SE3_ego[_image_ns(nusc, sd)], city_SE3_ego[FIXTURE_SWEEP_NS])
        pts_cam = pts_cam_h[:, :3]
        w, h = pinhole.width_px, pinhole.height_px
        # The devkit's filter, moved in (sure) or out (maybe) by 1e-3 px and m of depth: points within
        # float32 rounding of its edges may fall either way.
        u, v, z = uv_av2[:, 0], uv_av2[:, 1], pts_cam[:, 2]
        sure, maybe = ((z > 1.0 + m) & (u > 1 + m) & (u < w - 1 - m) & (v > 1 + m) & (v < h - 1 - m)
                       for m in (1e-3, -1e-3))
        pts, depth, _ = nusc.explorer.map_pointcloud_to_image(sample["data"]["LIDAR_TOP"], sd["token"])
        assert sure.sum() <= pts.shape[1] <= maybe.sum() and sure.sum() > 500
        assert maybe.sum() - sure.sum() <= 3
        dist, k = cKDTree(uv_av2[maybe]).query(pts[:2].T)
        budget_px = pinhole.intrinsics.fx_px * 1e-4 / pts_cam[maybe, 2][k]
        assert np.all(dist <= budget_px)
        assert np.abs(depth - pts_cam[maybe, 2][k]).max() < 1e-4


def test_lidar_top_maps_back_to_the_av2_sweep(nusc: NuScenes, native_db: Path, imaged_log):
    """pcd.bin (float32, LIDAR_TOP frame) -> written calibrated_sensor -> AV2 ego: within float32 rounding."""
    log_dir, _ = imaged_log
    sweep = pd.read_feather(log_dir / "sensors" / "lidar" / f"{FIXTURE_SWEEP_NS}.feather")
    xyz_egoS = sweep[["x", "y", "z"]].to_numpy().astype(np.float64)
    sd = nusc.get("sample_data", nusc.sample[0]["data"]["LIDAR_TOP"])
    rows = read_pcd_bin(native_db / sd["filename"])
    assert rows.shape == (len(sweep), 5) and rows.dtype == np.float32
    assert np.array_equal(rows[:, 3], sweep["intensity"])
    assert np.array_equal(rows[:, 4], sweep["laser_number"])
    cs = nusc.get("calibrated_sensor", sd["calibrated_sensor_token"])
    assert cs["translation"] == pytest.approx([0.943713, 0.0, 1.84023], abs=1e-9)  # nuScenes' LIDAR_TOP
    R = Quaternion(cs["rotation"]).rotation_matrix
    h = load_rig("av2").origin_height_m
    back = rows[:, :3].astype(np.float64) @ R.T + cs["translation"] - [0.0, 0.0, h]
    err = np.linalg.norm(back - xyz_egoS, axis=1)
    exact = (xyz_egoS + [0, 0, h] - cs["translation"]) @ R
    half_ulp = 0.5 * np.linalg.norm(np.spacing(np.abs(exact).astype(np.float32)).astype(np.float64), axis=1)
    assert np.all(err <= half_ulp + 1e-9)
    near = np.linalg.norm(exact, axis=1) < 8.0
    assert near.sum() > 1000 and err[near].max() < 1e-6


def test_annotations_match_av2_boxes_in_the_city_frame(nusc: NuScenes, native_db: Path, imaged_log):
    log_dir, _ = imaged_log
    av2 = pd.read_feather(log_dir / "annotations.feather")
    av2 = av2[av2.timestamp_ns == FIXTURE_SWEEP_NS].set_index("track_uuid")
    city_T_ego = read_city_SE3_ego(log_dir)[FIXTURE_SWEEP_NS]
    offset = np.array(_log_meta(native_db)["city_offset"])
    by_track = {}
    for inst in nusc.instance:
        ann = nusc.get("sample_annotation", inst["first_annotation_token"])
        assert inst["nbr_annotations"] == 1 and ann["prev"] == ann["next"] == ""
        by_track[ann["instance_token"]] = ann
    assert len(by_track) == (av2.category != "SIGN").sum() == 44
    from nuav2.nuscenes_db.tokens import make_token

    for uuid, row in av2.iterrows():
        rule = AV2_TO_NUSCENES[row.category]
        inst_token = make_token(log_dir.name, "instance", uuid)
        if rule.nuscenes is None:
            assert inst_token not in by_track
            continue
        ann = by_track[inst_token]
        assert ann["category_name"] == rule.nuscenes
        centre_city = city_T_ego.transform_point_cloud(np.array([[row.tx_m, row.ty_m, row.tz_m]]))[0]
        assert np.abs(np.array(ann["translation"]) + offset - centre_city).max() < 1e-9
        assert ann["size"] == pytest.approx([row.width_m, row.length_m, row.height_m], abs=1e-12)
        city_R_box = city_T_ego.rotation @ Quaternion([row.qw, row.qx, row.qy, row.qz]).rotation_matrix
        assert np.abs(Quaternion(ann["rotation"]).rotation_matrix - city_R_box).max() < 1e-12
        assert ann["num_lidar_pts"] == row.num_interior_pts
        assert ann["visibility_token"] in ("1", "2", "3", "4")  # measured: tests/test_visibility.py
        assert len(ann["attribute_tokens"]) <= 1


def test_detection_eval_of_ground_truth_gives_map_1(nusc: NuScenes, tmp_path):
    from nuscenes.eval.common.config import config_factory
    from nuscenes.eval.detection.evaluate import DetectionEval
    from nuscenes.eval.detection.utils import category_to_detection_name

    attr_names = {a["token"]: a["name"] for a in nusc.attribute}
    results = {}
    for sample in nusc.sample:
        boxes = []
        for tok in sample["anns"]:
            ann = nusc.get("sample_annotation", tok)
            det = category_to_detection_name(ann["category_name"])
            if det is None:
                continue
            vel = np.nan_to_num(nusc.box_velocity(tok)[:2]).tolist()
            attr = attr_names[ann["attribute_tokens"][0]] if ann["attribute_tokens"] else ""
            boxes.append({"sample_token": sample["token"], "translation": ann["translation"],
                          "size": ann["size"], "rotation": ann["rotation"], "velocity": vel,
                          "detection_name": det, "detection_score": 0.9, "num_pts": ann["num_lidar_pts"],
                          "attribute_name": attr})
        results[sample["token"]] = boxes
    result_path = tmp_path / "results.json"
    meta = {"use_camera": False, "use_lidar": True, "use_radar": False, "use_map": False,
            "use_external": False}
    result_path.write_text(json.dumps({"meta": meta, "results": results}))
    full = config_factory("detection_cvpr_2019")
    evaluation = DetectionEval(nusc, full, str(result_path), "av2_val", str(tmp_path / "eval"), verbose=False)
    present = {b.detection_name for b in evaluation.gt_boxes.all}  # classes with GT in range and with points
    assert {"car", "pedestrian", "bus"} <= present
    assert len(evaluation.pred_boxes.all) == len(evaluation.gt_boxes.all) > 20
    metrics, _ = evaluation.evaluate()
    for name in present:
        for dist_th in full.dist_ths:
            assert metrics.get_label_ap(name, dist_th) == pytest.approx(1.0), (name, dist_th)
    # The devkit config insists on all 10 classes (absent ones score AP 0), so mAP is taken over
    # the classes this split has ground truth for.
    assert np.mean([metrics.mean_dist_aps[name] for name in present]) == pytest.approx(1.0)


def test_conformance_checker_accepts_the_database(native_db: Path):
    from nuav2.nuscenes_db.validate import validate_database

    report = validate_database(native_db, VERSION, devkit=True)
    assert report.ok, report.format_text()
