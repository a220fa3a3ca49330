"""Category table, virtual LIDAR_TOP transform and point-in-box counting against oracles."""

from __future__ import annotations

import numpy as np
import pytest
from av2.datasets.sensor.constants import AnnotationCategories
from nuscenes.eval.detection.constants import ATTRIBUTE_NAMES
from nuscenes.eval.detection.utils import category_to_detection_name
from nuscenes.utils.color_map import get_colormap
from pyquaternion import Quaternion

from nuav2.geometry import T_from_quat_trans, egoS_T_egoT_from_heights, make_T, quat_to_rot, transform_points
from nuav2.nuscenes_db.annotations import count_points_in_boxes
from nuav2.nuscenes_db.categories import (
    AV2_TO_NUSCENES,
    NUSCENES_ATTRIBUTES,
    NUSCENES_CATEGORIES,
    UnknownCategoryError,
    attribute_for,
    category_rule,
)
from nuav2.nuscenes_db.lidar_top import lidar_T_egoS, read_pcd_bin, sweep_to_pcd_rows, write_pcd_bin
from nuav2.rig import load_rig
from nuav2.scene import LidarPoints


def test_every_av2_category_maps_to_a_devkit_category():
    assert {c.value for c in AnnotationCategories} <= set(AV2_TO_NUSCENES)
    assert len(NUSCENES_CATEGORIES) == 23
    assert set(NUSCENES_CATEGORIES) <= set(get_colormap())  # render_sample_data colours boxes by name
    assert set(NUSCENES_ATTRIBUTES) == set(ATTRIBUTE_NAMES)
    for av2_name, rule in AV2_TO_NUSCENES.items():
        assert rule.nuscenes is None or rule.nuscenes in NUSCENES_CATEGORIES, av2_name
    expect = {"REGULAR_VEHICLE": "car", "PEDESTRIAN": "pedestrian", "BUS": "bus", "ARTICULATED_BUS": "bus",
              "BOX_TRUCK": "truck", "CONSTRUCTION_CONE": "traffic_cone", "BOLLARD": "barrier",
              "BICYCLIST": "bicycle", "MOTORCYCLE": "motorcycle", "VEHICULAR_TRAILER": "trailer"}
    for av2_name, det in expect.items():
        assert category_to_detection_name(AV2_TO_NUSCENES[av2_name].nuscenes) == det
    assert category_rule("SIGN").nuscenes is None
    with pytest.raises(UnknownCategoryError, match="FLYING_SAUCER"):
        category_rule("FLYING_SAUCER")


def test_attributes_follow_motion_and_rider():
    assert attribute_for("REGULAR_VEHICLE", 3.0, True) == "vehicle.moving"
    assert attribute_for("REGULAR_VEHICLE", 0.1, True) == "vehicle.stopped"
    assert attribute_for("REGULAR_VEHICLE", 0.1, False) == "vehicle.parked"
    assert attribute_for("BICYCLIST", 0.0, False) == "cycle.with_rider"
    assert attribute_for("MOTORCYCLE", 5.0, True) == "cycle.without_rider"
    assert attribute_for("PEDESTRIAN", 1.2, True) == "pedestrian.moving"
    assert attribute_for("STROLLER", 0.0, False) == "pedestrian.standing"
    assert attribute_for("CONSTRUCTION_CONE", 0.0, False) is None
    assert attribute_for("STOP_SIGN", 0.0, False) is None


def _sweep(rng: np.random.Generator, n: int, scale: float) -> LidarPoints:
    """Half the points within 5 m, half out to ``scale``; float16 like AV2's files."""
    xyz = np.vstack([rng.uniform(-5, 5, size=(n // 2, 3)), rng.uniform(-scale, scale, size=(n - n // 2, 3))])
    xyz = xyz.astype(np.float16).astype(np.float64)
    intensity = rng.integers(0, 256, n).astype(np.float32)
    return LidarPoints(xyz, intensity, rng.integers(0, 64, n).astype(np.uint8))


def test_lidar_top_round_trip_to_source_ego_at_float32_precision(tmp_path):
    """egoS -> LIDAR_TOP (float64, cast to float32 on write) -> back: error <= the float32 rounding."""
    rig = load_rig("av2").with_origin_height(0.0)
    egoT_T_lidar = rig.lidar("LIDAR_TOP").ego_T_lidar
    egoS_T_egoT = egoS_T_egoT_from_heights(0.32, 0.0)
    lidar_T_ego = lidar_T_egoS(egoT_T_lidar, egoS_T_egoT)
    pts = _sweep(np.random.default_rng(0), 20000, 200.0)
    bad = LidarPoints(np.vstack([pts.xyz_ego, [[np.nan, 0, 0], [np.inf, 1, 1]]]),
                      np.append(pts.intensity, [1, 2]).astype(np.float32),
                      np.append(pts.laser_number, [3, 4]).astype(np.uint8))
    rows = sweep_to_pcd_rows(bad, lidar_T_ego)
    assert rows.dtype == np.float32 and rows.shape == (20000, 5)  # the two non-finite points dropped
    path = tmp_path / "x.pcd.bin"
    write_pcd_bin(path, rows)
    back = read_pcd_bin(path)
    assert np.array_equal(back, rows)
    assert np.array_equal(back[:, 3], pts.intensity) and np.array_equal(back[:, 4], pts.laser_number)
    # Back to the source ego frame in float64 through the same chain the devkit uses (pyquaternion).
    xyz_egoT = back[:, :3].astype(np.float64) @ quat_to_rot(Quaternion(matrix=egoT_T_lidar[:3, :3]).q).T
    xyz_egoT += egoT_T_lidar[:3, 3]
    xyz_egoS = transform_points(egoS_T_egoT, xyz_egoT)
    err = np.linalg.norm(xyz_egoS - pts.xyz_ego, axis=1)
    exact_lidar = transform_points(lidar_T_ego, pts.xyz_ego)
    ulp = np.spacing(np.abs(exact_lidar).astype(np.float32)).astype(np.float64)
    half_ulp = 0.5 * np.linalg.norm(ulp, axis=1)
    assert np.all(err <= half_ulp + 1e-9)
    near = np.linalg.norm(exact_lidar, axis=1) < 8.0
    assert near.sum() > 1000 and err[near].max() < 1e-6
    # In the LIDAR_TOP frame the AV2 nuScenes extrinsic turns ego +x (forward) into lidar +y.
    fwd = sweep_to_pcd_rows(LidarPoints(np.array([[10.943713, 0, 1.84023 - 0.32]]), np.zeros(1, np.float32),
                                        np.zeros(1, np.uint8)), lidar_T_ego)
    assert fwd[0, 1] == pytest.approx(10.0, abs=0.01) and abs(fwd[0, 0]) < 0.05


def test_pcd_bin_rejects_a_torn_file(tmp_path):
    p = tmp_path / "torn.pcd.bin"
    p.write_bytes(np.zeros(7, np.float32).tobytes())
    with pytest.raises(ValueError, match="not a multiple of 5"):
        read_pcd_bin(p)


def test_count_points_in_rotated_boxes_matches_devkit_points_in_box():
    from nuscenes.utils.data_classes import Box
    from nuscenes.utils.geometry_utils import points_in_box

    rng = np.random.default_rng(1)
    xyz = rng.uniform(-8, 8, size=(30000, 3))
    q = np.array([np.cos(0.35), 0.0, 0.0, np.sin(0.35)])
    ego_T_box = np.stack([T_from_quat_trans(q, [3.0, -2.0, 0.5]), make_T(np.eye(3), [-5.0, 5.0, 0.0]),
                          make_T(np.eye(3), [100.0, 100.0, 0.0])])
    lwh = np.array([[4.5, 1.9, 1.6], [0.5, 0.5, 1.8], [3.0, 3.0, 3.0]])
    counts = count_points_in_boxes(xyz, ego_T_box, lwh)
    for k in range(3):
        wlh = [lwh[k, 1], lwh[k, 0], lwh[k, 2]]
        box = Box(ego_T_box[k, :3, 3], wlh, Quaternion(matrix=ego_T_box[k, :3, :3]))
        assert counts[k] == int(points_in_box(box, xyz.T).sum())
    assert counts[0] > 50 and counts[2] == 0
