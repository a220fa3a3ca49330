"""Visualisation geometry: ground lifting, projection with near-plane clipping, layout, BEV, predictions."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from nuav2.geometry import T_from_quat_trans, T_to_quat_trans, make_T, transform_points
from nuav2.rig import load_rig
from nuav2.viz import (
    CLASS_COLORS_RGB,
    bev_panel,
    camera_rows,
    densify,
    ground_points_lidar,
    load_predictions,
    project_segments,
)

NUSC_LIDAR = T_from_quat_trans(
    [0.7077955119163518, -0.006492242056004365, 0.010646214713995808, -0.7063073142877817],
    [0.943713, 0.0, 1.84023],
)


@pytest.mark.parametrize("ground_z", [0.0, -0.32])
def test_lifted_points_lie_on_the_ego_ground_plane_above_their_lidar_xy(ground_z):
    rng = np.random.default_rng(0)
    xy = np.column_stack([rng.uniform(-15, 15, 100), rng.uniform(-30, 30, 100)])
    xyz = ground_points_lidar(xy, NUSC_LIDAR, ground_z)  # the nuScenes lidar is slightly tilted
    np.testing.assert_array_equal(xyz[:, :2], xy)
    np.testing.assert_allclose(transform_points(NUSC_LIDAR, xyz)[:, 2], ground_z, atol=1e-9)


def test_lifting_fails_clearly_for_a_lidar_lying_on_its_side():
    sideways = make_T(np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]]), [0, 0, 1.8])
    with pytest.raises(ValueError, match="parallel"):
        ground_points_lidar(np.zeros((2, 2)), sideways)


def test_densify_keeps_vertices_and_bounds_segment_length():
    xy = np.array([[0.0, 0.0], [3.0, 4.0], [3.0, 4.0], [3.0, 5.2]])
    out = densify(xy, 0.5)
    assert np.all(np.linalg.norm(np.diff(out, axis=0), axis=1) <= 0.5 + 1e-12)
    for v in xy:
        assert np.min(np.linalg.norm(out - v, axis=1)) < 1e-12
    np.testing.assert_array_equal(out[0], xy[0])
    np.testing.assert_array_equal(out[-1], xy[-1])


def _camera_projection() -> np.ndarray:
    """lidar2img of the nuScenes CAM_FRONT with the nuScenes LIDAR_TOP, same ego pose."""
    cam = load_rig("nuscenes").camera("CAM_FRONT")
    cam_T_lidar = np.linalg.inv(cam.ego_T_cam) @ NUSC_LIDAR
    K4 = np.eye(4)
    K4[:3, :3] = cam.K
    return K4 @ cam_T_lidar


def test_projection_matches_a_direct_pinhole_projection_in_front_of_the_camera():
    P = _camera_projection()
    cam = load_rig("nuscenes").camera("CAM_FRONT")
    xyz = ground_points_lidar(np.array([[-2.0, 5.0], [-1.0, 10.0], [1.0, 20.0], [3.0, 29.0]]), NUSC_LIDAR)
    seg = project_segments(xyz, P)
    p_cam = transform_points(np.linalg.inv(cam.ego_T_cam) @ NUSC_LIDAR, xyz)
    uv = (p_cam @ cam.K.T)[:, :2] / p_cam[:, 2:3]
    assert seg.shape == (3, 2, 2)
    np.testing.assert_allclose(seg[:, 0], uv[:-1], atol=1e-9)
    np.testing.assert_allclose(seg[:, 1], uv[1:], atol=1e-9)


def test_segments_behind_the_camera_are_dropped_and_crossing_ones_clipped_at_the_near_plane():
    P = _camera_projection()
    # a line from 10 m behind the car to 10 m ahead (lidar y is forward)
    xyz = ground_points_lidar(np.array([[0.0, -10.0], [0.0, -5.0], [0.0, 10.0]]), NUSC_LIDAR)
    seg = project_segments(xyz, P, near_m=0.5)
    assert seg.shape == (1, 2, 2) and np.all(np.isfinite(seg))
    # the clipped end is where the line is 0.5 m deep: invert the projection to check its depth
    A = P[:3, :3]
    uvw_far = P @ np.append(xyz[2], 1.0)
    assert seg[0, 1] == pytest.approx(uvw_far[:2] / uvw_far[2])
    depth = P[2, :3] @ xyz[1] + P[2, 3], P[2, :3] @ xyz[2] + P[2, 3]
    t = (0.5 - depth[0]) / (depth[1] - depth[0])
    clip_pt = xyz[1] + t * (xyz[2] - xyz[1])
    q = A @ clip_pt + P[:3, 3]
    assert q[2] == pytest.approx(0.5) and seg[0, 0] == pytest.approx(q[:2] / q[2])
    assert project_segments(xyz[:2], P).shape == (0, 2, 2)  # wholly behind: nothing


def _cams_of(rig_name: str) -> dict[str, dict]:
    cams = {}
    for c in load_rig(rig_name).cameras:
        q, _ = T_to_quat_trans(c.ego_T_cam)
        cams[c.channel] = {"sensor2ego_rotation": q.tolist()}
    return cams


def test_camera_rows_follow_the_drivers_view():
    assert camera_rows(_cams_of("nuscenes")) == [
        ["CAM_FRONT_LEFT", "CAM_FRONT", "CAM_FRONT_RIGHT"],
        ["CAM_BACK_LEFT", "CAM_BACK", "CAM_BACK_RIGHT"],
    ]
    ring = {k: v for k, v in _cams_of("av2").items() if k.startswith("ring_")}
    assert camera_rows(ring) == [
        ["ring_front_left", "ring_front_center", "ring_front_right"],
        ["ring_side_left", "ring_rear_left", "ring_rear_right", "ring_side_right"],
    ]


def test_bev_panel_draws_classes_where_they_are():
    divider = np.array([[0.0, -20.0], [0.0, 20.0]])  # along the lidar y axis, through the ego
    crossing = np.array([[-10.0, 20.0], [10.0, 20.0], [10.0, 24.0], [-10.0, 24.0], [-10.0, 20.0]])
    img = bev_panel([("divider", divider), ("ped_crossing", crossing)], [], height_px=600)
    assert img.shape == (600, 300, 3)
    yellow = np.array(CLASS_COLORS_RGB["divider"])[::-1]  # image is BGR
    blue = np.array(CLASS_COLORS_RGB["ped_crossing"])[::-1]
    # forward is up: y = -10 m is 400 px down, x = 0 the centre column
    assert np.all(img[400, 149:151] == yellow)
    assert np.all(img[100, 100] == blue)  # (x = -5, y = 20): the crossing's lower edge


def test_predictions_load_from_list_or_dict_results(tmp_path):
    vec = {"pts": [[0, 0], [1, 1]], "pts_num": 2, "cls_name": "divider", "type": 0, "confidence_level": 0.7}
    as_list = tmp_path / "list.json"
    as_list.write_text(json.dumps({"meta": {}, "results": [{"sample_token": "a", "vectors": [vec]}]}))
    as_dict = tmp_path / "dict.json"
    as_dict.write_text(json.dumps({"meta": {}, "results": {"a": {"vectors": [vec]}}}))
    for path in (as_list, as_dict):
        ((cls, pts, score),) = load_predictions(path)["a"]
        assert cls == "divider" and pts.shape == (2, 2) and score == pytest.approx(0.7)
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"meta": {}}))
    with pytest.raises(ValueError, match="bad.json"):
        load_predictions(bad)


def test_yaw_sorting_is_robust_to_a_camera_looking_straight_back():
    q_back = [math.cos(math.pi / 2), 0.0, 0.0, math.sin(math.pi / 2)]  # ego yaw 180 deg
    cams = _cams_of("nuscenes")
    cams["CAM_BACK"]["sensor2ego_rotation"] = T_to_quat_trans(
        T_from_quat_trans(q_back, [0, 0, 0]) @ load_rig("nuscenes").camera("CAM_FRONT").ego_T_cam
    )[0].tolist()
    assert camera_rows(cams)[1] == ["CAM_BACK_LEFT", "CAM_BACK", "CAM_BACK_RIGHT"]
