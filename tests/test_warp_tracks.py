"""Box tracks at any time, static lidar aggregation and the ground surface: hand-made cases and the real
AV2 fixture checked against the av2 package's own poses, cuboids, point counts and ground heights."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from nuav2.geometry import make_T, quat_to_rot
from nuav2.rig import load_rig
from nuav2.scene import Annotations, SceneLog
from nuav2.warp.depth_proxy import GroundSurface
from nuav2.warp.lidar_cloud import CloudConfig, LidarCloud, points_in_boxes
from nuav2.warp.tracks import BoxTracks

MS = 1_000_000


def _scene(annotations: Annotations) -> SceneLog:
    ts = np.array([0, 1000 * MS], dtype=np.int64)
    poses = np.stack([make_T(np.eye(3), [100.0, 50.0, 10.0]), make_T(np.eye(3), [110.0, 50.0, 10.0])])
    return SceneLog("log", "synthetic", "PIT", "PIT_city_1", load_rig("av2"), ts, poses, [], {}, annotations,
                    None)


def _yaw_q(yaw: float) -> list[float]:
    return [np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)]


def test_tracks_interpolate_extrapolate_and_end():
    # Track "a": in the ego frame at t = 0, 100, 200 ms; track "b": a single row; one duplicated row.
    ts = np.array([0, 100, 200, 200, 100], dtype=np.int64) * MS
    ann = Annotations(ts, np.array(["a", "a", "a", "a", "b"], object), np.array(["CAR"] * 5, object),
                      np.ones((5, 3)),
                      np.array([_yaw_q(0.0), _yaw_q(0.1), _yaw_q(0.2), _yaw_q(0.2), _yaw_q(1.0)]),
                      np.array([[5.0, 0, 0], [6.0, 0, 0], [7.0, 0, 0], [7.0, 0, 0], [1.0, 2.0, 0.0]]),
                      np.zeros(5, np.int64))
    scene = _scene(ann)
    tracks = BoxTracks.from_scene(scene)
    assert len(tracks) == 2 and len(tracks.timestamp_ns) == 4
    # Ego moves +10 m/s along x, the box +10 m/s relative to it: +20 m/s in the city.
    mid = tracks.at(50 * MS)
    a = int(np.flatnonzero(tracks.track_ids[mid.track] == "a")[0])
    np.testing.assert_allclose(mid.city_T_box[a, :3, 3], [100.5 + 5.5, 50.0, 10.0], atol=1e-9)
    np.testing.assert_allclose(mid.city_T_box[a, :3, :3], quat_to_rot(_yaw_q(0.05)), atol=1e-12)
    # 50 ms past the end: extrapolated along the last segment; 80 ms past: gone (tolerance 60 ms).
    late = tracks.at(250 * MS)
    a = int(np.flatnonzero(tracks.track_ids[late.track] == "a")[0])
    np.testing.assert_allclose(late.city_T_box[a, :3, 3], [102.5 + 7.5, 50.0, 10.0], atol=1e-9)
    assert "a" not in set(tracks.track_ids[tracks.at(280 * MS).track])
    # The single-row track holds its pose within the tolerance, and is absent beyond it.
    b_pose = tracks.at(140 * MS)
    b = int(np.flatnonzero(tracks.track_ids[b_pose.track] == "b")[0])
    np.testing.assert_allclose(b_pose.city_T_box[b, :3, 3], [102.0, 52.0, 10.0], atol=1e-9)
    assert "b" not in set(tracks.track_ids[tracks.at(300 * MS).track])
    empty = BoxTracks.from_scene(_scene(Annotations.empty()))
    assert len(empty) == 0 and len(empty.at(0)) == 0
    # Rows outside the pose table are left out instead of failing the log.
    outside = dataclasses.replace(ann, timestamp_ns=ann.timestamp_ns + np.array([0, 0, 0, 0, 5000 * MS]))
    assert BoxTracks.from_scene(_scene(outside)).track_ids.tolist() == ["a"]


def test_points_in_rotated_boxes():
    box = make_T(quat_to_rot(_yaw_q(np.pi / 4)), [10.0, 0.0, 1.0])[None]
    pts = np.array([[10.0, 0.0, 1.0], [11.3, 1.3, 1.0], [11.3, -1.3, 1.0], [10.0, 0.0, 2.2]])
    inside = points_in_boxes(pts, box, np.array([[4.0, 1.0, 2.0]]), margin_m=0.0)
    assert inside.tolist() == [True, True, False, False]
    # Point 3 is 1.84 m off the box axis sideways (outside even with the margin); point 4 is 0.2 m above.
    grown = points_in_boxes(pts, box, np.array([[4.0, 1.0, 2.0]]), margin_m=0.25)
    assert grown.tolist() == [True, True, False, True]


@pytest.fixture(scope="module")
def fixture_scene(av2_fixture_log: Path, av2_fixture_calibration: Path):
    from converters.av2 import read_log

    return read_log(av2_fixture_log, av2_fixture_calibration, require_cameras=False)


def test_tracks_match_av2_cuboids_in_the_city_frame(fixture_scene, av2_fixture_log: Path):
    from av2.structures.cuboid import CuboidList
    from av2.utils.io import read_city_SE3_ego

    tracks = BoxTracks.from_scene(fixture_scene)
    cuboids = CuboidList.from_feather(av2_fixture_log / "annotations.feather")
    city_SE3_ego = read_city_SE3_ego(av2_fixture_log)
    for ts in np.unique([c.timestamp_ns for c in cuboids])[::40]:
        ours = tracks.at(int(ts))
        theirs = [c for c in cuboids if c.timestamp_ns == ts]
        assert len(ours) == len(theirs) > 10
        pose = city_SE3_ego[int(ts)]
        for c in theirs:
            city = pose.compose(c.dst_SE3_object).transform_matrix
            k = int(np.argmin(np.linalg.norm(ours.city_T_box[:, :3, 3] - city[:3, 3], axis=1)))
            np.testing.assert_allclose(ours.city_T_box[k], city, atol=1e-6)
            np.testing.assert_allclose(ours.size_lwh[k], [c.length_m, c.width_m, c.height_m])


def test_lidar_cloud_drops_exactly_the_points_av2_counts_inside_boxes(fixture_scene):
    ref = fixture_scene.lidar_sweeps[0]
    ann = fixture_scene.annotations
    rows = ann.at(ref.timestamp_ns)
    tracks = BoxTracks.from_scene(fixture_scene)
    keep_all = LidarCloud(fixture_scene, BoxTracks.from_scene(dataclasses.replace(
        fixture_scene, annotations=Annotations.empty())), CloudConfig(ground_band_m=0.0))
    no_boxes, _ = keep_all.sweep_points(0)
    cloud = LidarCloud(fixture_scene, tracks, CloudConfig(ground_band_m=0.0, box_margin_m=0.0))
    pts, radius = cloud.sweep_points(0)
    removed = len(no_boxes) - len(pts)
    # AV2's own per-box counts (num_interior_pts) sum to what the boxes remove, up to points in two boxes.
    assert abs(removed - int(ann.num_interior_pts[rows].sum())) <= 0.01 * removed + 5
    boxes = tracks.at(ref.timestamp_ns)
    assert not np.any(points_in_boxes(pts, boxes.city_T_box, boxes.size_lwh, margin_m=-1e-6))
    assert np.all(radius >= CloudConfig().min_radius_m) and np.all(np.isfinite(pts))
    # The default ground band drops the points on the ground surface (this street: ~15 % of them) only.
    surface = GroundSurface.under_ego(fixture_scene.city_T_ego_at(ref.timestamp_ns),
                                      fixture_scene.rig.origin_height_m, fixture_scene.ground_height)
    cloud = LidarCloud(fixture_scene, tracks, CloudConfig(box_margin_m=0.0), ground_at=lambda t: surface)
    off_ground, _ = cloud.sweep_points(0)
    band = np.abs(pts[:, 2] - surface.height(pts[:, :2])) <= CloudConfig().ground_band_m
    assert len(off_ground) == len(pts) - band.sum() and band.sum() > 0.1 * len(pts)


def test_ground_heights_and_vertical_rays_match_av2_map(fixture_scene, av2_fixture_log: Path):
    from av2.map.map_api import ArgoverseStaticMap

    avm = ArgoverseStaticMap.from_map_dir(av2_fixture_log / "map", build_raster=True)
    ground = GroundSurface.under_ego(fixture_scene.city_T_ego[0], 0.32, fixture_scene.ground_height)
    rng = np.random.default_rng(0)
    xy = fixture_scene.city_T_ego[::50, :2, 3][:, None, :] + rng.uniform(-15, 15, (1, 20, 2))
    xy = xy.reshape(-1, 2)
    theirs = avm.raster_ground_height_layer.get_ground_height_at_xy(np.column_stack([xy, np.zeros(len(xy))]))
    known = np.isfinite(theirs)
    assert known.sum() > 100
    # At cell centres our bilinear height is the cell's value, which av2 returns for the whole cell.
    r = fixture_scene.ground_height
    centres = ((np.floor(r.s * (xy @ r.R.T + r.t)) + 0.5) / r.s - r.t) @ r.R
    layer = avm.raster_ground_height_layer
    theirs_c = layer.get_ground_height_at_xy(np.column_stack([centres, np.zeros(len(xy))]))
    np.testing.assert_allclose(ground.height(centres)[known], theirs_c[known], atol=1e-3)  # float16 raster
    # Between centres it lies within the range of av2's values at the four neighbouring cells.
    step = 1.0 / r.s
    neigh = np.stack([layer.get_ground_height_at_xy(
        np.column_stack([xy + [dx, dy], np.zeros(len(xy))])) for dx in (-step / 2, step / 2)
        for dy in (-step / 2, step / 2)], 1)
    ok = known & np.isfinite(neigh).all(1)
    ours = ground.height(xy)[ok]
    assert np.all(ours >= neigh[ok].min(1) - 1e-3) and np.all(ours <= neigh[ok].max(1) + 1e-3)
    # A vertical ray from 5 m above lands on that height (the compiled caster reads the raster the same way).
    origin_z = ours[:30] + 5.0
    t = np.array([ground.intersect(np.array([x, y, z]), np.array([[0.0, 0.0, -1.0]]))[0]
                  for (x, y), z in zip(xy[ok][:30], origin_z)])
    np.testing.assert_allclose(origin_z - t, ours[:30], atol=1e-3)
    # The ego origin is ~0.32 m above the ground it stands on (fixture README).
    ego = fixture_scene.city_T_ego[::100]
    h = ego[:, 2, 3] - ground.height(ego[:, :2, 3])
    assert np.all(np.abs(h - 0.32) < 0.05)


def test_moving_tracks_are_told_from_parked_ones_and_selected():
    """A parked car with label jitter is not moving; a driving one is; ``select`` keeps rows and order."""
    rng = np.random.default_rng(0)
    n = 20
    ts = np.arange(n, dtype=np.int64) * 100_000_000
    parked = np.array([5.0, 2.0, 0.8]) + rng.normal(0, 0.05, (n, 3))
    driving = np.column_stack([np.arange(n) * 0.9, np.zeros(n), np.full(n, 0.8)])
    walker = np.column_stack([np.zeros(n), np.arange(n) * 0.14, np.full(n, 0.9)])
    q = np.tile([1.0, 0.0, 0.0, 0.0], (3 * n, 1))
    tracks = BoxTracks(np.array(["p", "d", "w"], object), np.array([0, n, 2 * n, 3 * n]), np.tile(ts, 3), q,
                       np.concatenate([parked, driving, walker]), np.tile([4.0, 2.0, 1.6], (3 * n, 1)),
                       np.array(["REGULAR_VEHICLE", "REGULAR_VEHICLE", "PEDESTRIAN"], object))
    moving = tracks.moving()
    assert moving.tolist() == [False, True, True]
    sel = tracks.select(moving)
    assert sel.track_ids.tolist() == ["d", "w"] and sel.starts.tolist() == [0, n, 2 * n]
    np.testing.assert_array_equal(sel.city_t_box, np.concatenate([driving, walker]))
    assert sel.category.tolist() == ["REGULAR_VEHICLE", "PEDESTRIAN"]
    at = sel.at(int(ts[5]))
    assert len(at) == 2 and sel.track_ids[at.track].tolist() == ["d", "w"]
