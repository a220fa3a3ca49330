"""Ground-height raster lookup (oracle: av2's own map API) and the per-log ego-origin-height estimate."""

from __future__ import annotations

import numpy as np
import pytest
from av2.map.map_api import ArgoverseStaticMap

from converters.av2 import read_log
from nuav2.geometry import translation_T
from nuav2.ground_height import estimate_origin_height, origin_heights
from nuav2.rig import load_rig
from nuav2.scene import Annotations, GroundHeightRaster, SceneLog


@pytest.fixture(scope="module")
def scene(av2_fixture_log, av2_fixture_calibration):
    return read_log(av2_fixture_log, av2_fixture_calibration, require_cameras=False)


def test_fixture_origin_height_is_av2_nominal(scene):
    est = estimate_origin_height(scene)
    assert est.n == 2637  # the raster covers every pose of this log
    assert est.mean_m == pytest.approx(0.32, abs=0.01)
    assert 0.0 < est.std_m < 0.02
    assert 0.25 < est.min_m <= est.mean_m <= est.max_m < 0.40
    assert est.mean_m == pytest.approx(scene.rig.origin_height_m, abs=0.01)


def test_raster_lookup_matches_av2_map_api(scene, av2_fixture_log):
    """Random city points over (and beyond) the raster: same value or both NaN as av2's lookup."""
    avm = ArgoverseStaticMap.from_map_dir(av2_fixture_log / "map", build_raster=True)
    raster = scene.ground_height
    h, w = raster.heights.shape
    rng = np.random.default_rng(0)
    # Image coordinates from -50 px to size + 50 px, mapped back to the city frame.
    p_img = np.column_stack([rng.uniform(-50, w + 50, 20_000), rng.uniform(-50, h + 50, 20_000)])
    xy_city = (p_img / raster.s - raster.t) @ raster.R  # inverse of p = s (R xy + t), R orthonormal
    ours = raster.height_at(xy_city)
    theirs = avm.raster_ground_height_layer.get_ground_height_at_xy(xy_city)
    # av2 truncates towards zero, so -1 < p < 0 reads row/column 0; we floor (outside -> NaN).
    edge_band = np.any((p_img > -1) & (p_img < 0), axis=1)
    assert edge_band.sum() < 100
    assert np.array_equal(ours[~edge_band], theirs[~edge_band], equal_nan=True)
    assert np.all(np.isnan(ours[edge_band]))
    inside = (p_img[:, 0] >= 0) & (p_img[:, 0] < w) & (p_img[:, 1] >= 0) & (p_img[:, 1] < h)
    assert np.isfinite(ours[inside]).sum() > 5_000  # the comparison covers real heights, not just NaN
    assert np.all(np.isnan(ours[~inside]))


def test_raster_round_trip_with_rotation():
    """City point of each pixel centre (inverse Sim(2), rotated and scaled) reads back that pixel."""
    theta = np.radians(30.0)
    R = np.array([[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]])
    heights = np.arange(12 * 17, dtype=np.float32).reshape(12, 17)
    raster = GroundHeightRaster(heights=heights, R=R, t=np.array([-4000.5, 2500.25]), s=1 / 0.3)
    rows, cols = np.mgrid[0:12, 0:17]
    p_img = np.column_stack([cols.ravel() + 0.5, rows.ravel() + 0.5])
    xy_city = (p_img / raster.s - raster.t) @ R
    assert np.array_equal(raster.height_at(xy_city), heights.ravel().astype(np.float64))
    assert np.isnan(raster.height_at(xy_city[:1] + 1e5)).all()


def _flat_scene(ground_z: float, ego_z: np.ndarray, heights: np.ndarray | None = None) -> SceneLog:
    heights = np.full((10, 10), ground_z, np.float32) if heights is None else heights
    raster = GroundHeightRaster(heights=heights, R=np.eye(2), t=np.zeros(2), s=1.0)
    poses = np.stack([translation_T(2.0 + i, 3.0, z) for i, z in enumerate(ego_z)])
    return SceneLog(log_id="flat", source="synthetic", city="TST", city_frame="TST_city_0",
                    rig=load_rig("av2"),
                    pose_timestamps_ns=np.arange(len(ego_z), dtype=np.int64) * 10, city_T_ego=poses,
                    lidar_sweeps=[], camera_frames={}, annotations=Annotations.empty(), vector_map=None,
                    ground_height=raster)


def test_estimate_on_a_flat_world_is_exact():
    scene = _flat_scene(70.0, np.array([70.5, 70.5, 70.25, 70.75]))
    est = estimate_origin_height(scene)
    assert (est.mean_m, est.min_m, est.max_m, est.n) == (0.5, 0.25, 0.75, 4)
    assert est.std_m == pytest.approx(np.std([0.5, 0.5, 0.25, 0.75]))


def test_estimate_skips_unknown_ground_and_refuses_none():
    heights = np.full((10, 10), 10.0, np.float32)
    heights[3, 2] = np.nan  # under the first pose (x=2.0, y=3.0)
    scene = _flat_scene(10.0, np.array([99.0, 10.3, 10.3]), heights)
    assert np.isnan(origin_heights(scene)[0])
    est = estimate_origin_height(scene)
    assert est.n == 2 and est.mean_m == pytest.approx(0.3, abs=1e-6)
    empty = _flat_scene(10.0, np.array([10.3]), np.full((10, 10), np.nan, np.float32))
    with pytest.raises(ValueError, match="log flat: the ground raster has no value"):
        estimate_origin_height(empty)
    no_raster = _flat_scene(10.0, np.array([10.3]))
    no_raster.ground_height = None
    with pytest.raises(ValueError, match="no ground-height raster"):
        estimate_origin_height(no_raster)


def test_scene_pose_table_is_built_once_and_rebuilt_when_replaced():
    """SceneLog.city_T_ego_at checks and converts its poses once; a replaced table is not served stale."""
    from nuav2.geometry import interpolate_poses

    scene = _flat_scene(0.0, np.array([0.0, 1.0, 2.0, 3.0]))
    q = np.array([0, 5, 12, 30], np.int64)
    np.testing.assert_array_equal(scene.city_T_ego_at(q), interpolate_poses(scene.pose_timestamps_ns,
                                                                            scene.city_T_ego, q))
    table = scene.__dict__["_pose_table"][1]
    scene.city_T_ego_at(7)
    assert scene.__dict__["_pose_table"][1] is table  # reused
    scene.city_T_ego = scene.city_T_ego + translation_T(0.0, 0.0, 10.0)[None] - np.eye(4)[None]
    assert scene.city_T_ego_at(10)[2, 3] == pytest.approx(11.0)  # the new table, not the cached one
    with pytest.raises(ValueError, match="outside the pose table"):
        scene.city_T_ego_at(1000)
