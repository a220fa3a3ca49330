"""Seeding: motion classification, voxel/box geometry, z-buffered colouring, LiDAR aggregation on real AV2."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from nuav2.geometry import T_from_quat_trans, T_inverse, make_T, translation_T
from nuav2.rig import CameraSpec
from nuav2.splat.actors import build_tracks, is_moving, track_motion
from nuav2.splat.colouring import colour_seeds, zbuffer_visible
from nuav2.splat.ground import GroundSurface, ground_seeds
from nuav2.splat.init import InitConfig
from nuav2.splat.lidar_seeds import (
    aggregate_lidar,
    box_surface_points,
    knn_scales,
    points_in_box,
    voxel_downsample,
)
from nuav2.splat.scene_model import TrackPoses, scene_frame_for
from nuav2.splat.views import Projection, SourceView, bilinear

CAM_R_FORWARD_X = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def test_voxel_downsample_centroids():
    pts = np.array([[0.01, 0.01, 0.01], [0.09, 0.05, 0.03], [0.55, 0.0, 0.0], [-0.05, 0.0, 0.0]])
    out = voxel_downsample(pts, 0.1)
    expect = {(-0.05, 0.0, 0.0), (0.05, 0.03, 0.02), (0.55, 0.0, 0.0)}
    assert {tuple(np.round(p, 6)) for p in out} == expect
    assert len(voxel_downsample(np.zeros((0, 3)), 0.1)) == 0
    with pytest.raises(ValueError, match="voxel"):
        voxel_downsample(pts, 0.0)


def test_points_in_rotated_box_roundtrip():
    rng = np.random.default_rng(0)
    frame_T_box = T_from_quat_trans(rng.normal(size=4), [10.0, -3.0, 1.0])
    size = np.array([4.0, 2.0, 1.5])
    inside_box = rng.uniform(-0.49, 0.49, (50, 3)) * size
    outside_box = inside_box.copy()
    outside_box[:, 0] = np.sign(outside_box[:, 0] + 1e-9) * (size[0] / 2 + 0.3)
    pts = np.concatenate([inside_box, outside_box]) @ frame_T_box[:3, :3].T + frame_T_box[:3, 3]
    m = points_in_box(pts, T_inverse(frame_T_box), size, margin=0.0)
    assert m[:50].all() and not m[50:].any()
    assert points_in_box(pts, T_inverse(frame_T_box), size, margin=0.35)[50:].all()


def test_box_surface_points_lie_on_faces():
    size = np.array([4.0, 2.0, 1.5])
    p = box_surface_points(size, 500, np.random.default_rng(1))
    rel = np.abs(p) / (size / 2)
    assert np.all(rel <= 1 + 1e-9)
    assert np.allclose(rel.max(axis=1), 1.0)


def _track(centres: np.ndarray) -> TrackPoses:
    ts = np.arange(len(centres), dtype=np.int64) * 100_000_000
    return TrackPoses("t", "REGULAR_VEHICLE", np.array([4.0, 2.0, 1.5]), ts,
                      np.stack([translation_T(*c) for c in centres]))


def test_motion_rule_separates_jitter_from_driving():
    rng = np.random.default_rng(2)
    parked = _track(np.column_stack([rng.normal(0, 0.05, 150), rng.normal(0, 0.05, 150), np.zeros(150)]))
    path, std = track_motion(parked)
    assert path > 1.0 and std < 0.3  # long jitter path, tiny spread: must stay background
    cfg = InitConfig()
    assert not is_moving(parked, cfg)
    driving = _track(np.column_stack([np.linspace(0, 10, 20), np.zeros(20), np.zeros(20)]))
    assert is_moving(driving, cfg)
    assert not is_moving(_track(np.zeros((1, 3))), cfg)


def test_bilinear_sampling_oracle():
    img = np.arange(4 * 5 * 3, dtype=np.float32).reshape(4, 5, 3)
    np.testing.assert_allclose(bilinear(img, np.array([2.0]), np.array([1.0]))[0], img[1, 2])
    mid = bilinear(img, np.array([2.5]), np.array([1.5]))[0]
    np.testing.assert_allclose(mid, img[1:3, 2:4].reshape(-1, 3).mean(0))
    np.testing.assert_allclose(bilinear(img, np.array([-3.0]), np.array([9.0]))[0], img[3, 0])


def _view(image: np.ndarray, city_T_cam: np.ndarray, ts: int = 0, f: float = 20.0) -> SourceView:
    h, w = image.shape[:2]
    K = np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1.0]])
    cam = CameraSpec("CAM", w, h, K, np.eye(4))
    return SourceView(0, "CAM", ts, Path("unused.jpg"), cam, city_T_cam, np.ones((h, w), bool),
                      _image=image.astype(np.float32))


def test_colouring_respects_occlusion_and_moves_objects():
    """A point hidden behind a nearer one takes no colour; object seeds are coloured at the view time."""
    h, w = 21, 31
    img = np.zeros((h, w, 3), np.float32)
    img[:, : w // 2] = [1.0, 0.0, 0.0]  # left half red
    img[:, w // 2 :] = [0.0, 1.0, 0.0]  # right half green
    city_T_cam = make_T(CAM_R_FORWARD_X, [0, 0, 0])
    view = _view(img, city_T_cam, ts=50)
    # A small wall of near points on the optical axis, one point right behind it, one far to the left.
    wall = np.array([[5.0, y, z] for y in np.linspace(-0.3, 0.3, 7) for z in np.linspace(-0.3, 0.3, 7)])
    behind = np.array([[12.0, 0.0, 0.0]])
    left = np.array([[10.0, 3.0, 0.0]])  # +y world = left in the image
    bg = np.concatenate([wall, behind, left])
    # An object whose box sits at y = -3 (right side) at t=50 and the box-frame seed at its centre.
    track = TrackPoses("car", "REGULAR_VEHICLE", np.array([1.0, 1.0, 1.0]), np.array([0, 100], np.int64),
                       np.stack([translation_T(10.0, -6.0, 0.0), translation_T(10.0, 0.0, 0.0)]))
    cfg = InitConfig(zbuf_cell_px=1, sky_dilate_px=0)
    bg_col, obj_col = colour_seeds(bg, {"car": np.zeros((1, 3))}, {"car": track}, [view], np.eye(4), cfg)
    assert np.isfinite(bg_col.rgb[: len(wall)]).all()
    assert np.isnan(bg_col.rgb[len(wall)]).all() and bg_col.seen[len(wall)] == 0  # occluded
    np.testing.assert_allclose(bg_col.rgb[-1], [1.0, 0.0, 0.0])
    np.testing.assert_allclose(obj_col["car"].rgb[0], [0.0, 1.0, 0.0])
    # The sky mask never covers pixels where seeds project, and never looks down.
    sky = bg_col.sky_masks[0]
    assert not sky[h // 2, w // 2] and not sky[-1].any() and sky[0].any()


def _zbuffer_numpy(u, v, z, width, height, cell_px, rel_tol, abs_tol_m, valid):
    """The z-buffer test as numpy spells it (the former implementation): the compiled kernel's oracle."""
    c = max(1, cell_px)
    gw, gh = (width + c - 1) // c, (height + c - 1) // c
    cell = (np.clip(np.round(v).astype(np.int64) // c, 0, gh - 1) * gw
            + np.clip(np.round(u).astype(np.int64) // c, 0, gw - 1))
    zmin = np.full(gw * gh, np.inf, np.float32)
    np.minimum.at(zmin, cell, z.astype(np.float32))
    zmin = cv2.erode(zmin.reshape(gh, gw), np.ones((3, 3), np.uint8), borderType=cv2.BORDER_REPLICATE).ravel()
    vis = z <= zmin[cell] * (1 + rel_tol) + abs_tol_m
    if valid is None:
        return vis
    pu, pv = np.round(u).astype(np.int64), np.round(v).astype(np.int64)
    return vis & valid[np.clip(pv, 0, height - 1), np.clip(pu, 0, width - 1)]


@pytest.mark.parametrize("cell_px,dtype,masked", [(1, np.float64, True), (2, np.float64, True),
                                                   (3, np.float64, False), (2, np.float32, True),
                                                   (4, np.float32, False)])
def test_zbuffer_kernel_matches_numpy_oracle(cell_px, dtype, masked):
    """Half-pixel ties (round half to even), image edges, depth ties at the tolerance, masked pixels,
    float32 points (the exposure solves) and float64 (seed colouring)."""
    rng = np.random.default_rng(cell_px)
    width, height, n = 37, 23, 5000
    u = rng.uniform(-0.5, width - 0.5, n)
    v = rng.uniform(-0.5, height - 0.5, n)
    u[:500] = np.round(u[:500]) + 0.5  # exact .5: banker's rounding decides the cell
    v[250:750] = np.round(v[250:750]) - 0.5
    z = rng.uniform(1.0, 60.0, n)
    z[1000:1200] = 10.0
    u, v, z = u.astype(dtype), v.astype(dtype), z.astype(dtype)
    valid = rng.random((height, width)) > 0.2 if masked else None
    cfg = InitConfig(zbuf_cell_px=cell_px)
    want = _zbuffer_numpy(u, v, z, width, height, cell_px, cfg.zbuf_rel_tol, cfg.zbuf_abs_tol_m, valid)
    got = zbuffer_visible(Projection(np.arange(n), u, v, z), width, height, cfg, valid)
    assert 0 < want.sum() < n
    np.testing.assert_array_equal(got, want)


def test_colouring_on_two_threads_equals_one():
    """Views are projected on worker threads but merged in order: the result is the same bytes."""
    rng = np.random.default_rng(0)
    h, w = 24, 32
    views = []
    for k in range(9):
        img = rng.random((h, w, 3)).astype(np.float32)
        city_T_cam = make_T(CAM_R_FORWARD_X, [0.4 * k, 0.2 * (k % 3), 0.0])
        view = _view(img, city_T_cam, ts=10 * k)
        view.index = k
        views.append(view)
    bg = np.column_stack([rng.uniform(3, 30, 4000), rng.uniform(-8, 8, 4000), rng.uniform(-2, 3, 4000)])
    track = TrackPoses("car", "REGULAR_VEHICLE", np.array([2.0, 1.0, 1.0]), np.array([0, 100], np.int64),
                       np.stack([translation_T(8.0, -3.0, 0.0), translation_T(12.0, 3.0, 0.0)]))
    car = rng.uniform(-0.5, 0.5, (200, 3))
    cfg = InitConfig()
    one = colour_seeds(bg, {"car": car}, {"car": track}, views, np.eye(4), cfg, threads=1)
    two = colour_seeds(bg, {"car": car}, {"car": track}, views, np.eye(4), cfg, threads=2)
    for a, b in ((one[0], two[0]), (one[1]["car"], two[1]["car"])):
        np.testing.assert_array_equal(a.rgb, b.rgb)
        np.testing.assert_array_equal(a.seen, b.seen)
    assert (one[0].seen > 0).sum() > 100 and one[0].seen.max() > 1  # seen, and by several views
    for k in one[0].sky_masks:
        np.testing.assert_array_equal(one[0].sky_masks[k], two[0].sky_masks[k])


def test_knn_scales_regular_grid():
    g = np.stack(np.meshgrid(np.arange(5.0), np.arange(5.0), [0.0]), -1).reshape(-1, 3) * 0.2
    s = knn_scales(g, 3, 0.01, 1.0)
    assert np.all(s >= 0.2 - 1e-9) and np.median(s) == pytest.approx(0.2)
    assert len(knn_scales(np.zeros((0, 3)))) == 0


@pytest.fixture(scope="module")
def fixture_scene(av2_fixture_log, av2_fixture_calibration):
    from converters.av2 import read_log

    return read_log(av2_fixture_log, av2_fixture_calibration, require_cameras=False)


def test_aggregate_real_av2_sweep_routes_moving_box_points(fixture_scene):
    scene = fixture_scene
    cfg = InitConfig()
    city_T_scene = scene_frame_for(scene.city_T_ego[0])
    scene_T_city = T_inverse(city_T_scene)
    tracks = build_tracks(scene, scene_T_city)
    moving = {t.track_id: t for t in tracks if is_moving(t, cfg)}
    assert 0 < len(moving) < len(tracks)  # the real log has both parked and moving actors
    agg = aggregate_lidar(scene, scene_T_city, moving, cfg)
    n_obj = sum(len(p) for p in agg.objects.values())
    assert n_obj > 0 and len(agg.background) + n_obj == agg.n_points
    ann, ts = scene.annotations, int(scene.lidar_sweeps[0].timestamp_ns)
    scene_T_ego = scene_T_city @ scene.city_T_ego_at(ts)
    for row in ann.at(ts):
        tid = str(ann.track_id[row])
        if tid not in moving:
            continue
        ego_T_box = T_from_quat_trans(ann.ego_q_box[row], ann.ego_t_box[row])
        half = ann.size_lwh[row] / 2 + cfg.box_margin_m
        assert np.all(np.abs(agg.objects[tid]) <= half + 1e-9)
        # No background point lies in this moving box (oracle: the box test in the scene frame).
        box_T_scene = T_inverse(scene_T_ego @ ego_T_box)
        margin = cfg.box_margin_m - 1e-6
        assert not points_in_box(agg.background, box_T_scene, ann.size_lwh[row], margin).any()
    # Scene coordinates are small (recentred) even though the city frame is km-scale.
    assert np.abs(agg.background).max() < 500.0 and np.abs(scene.city_T_ego[0, :2, 3]).max() > 1000.0


def test_ground_seeds_follow_raster_and_skip_occupied(fixture_scene):
    scene = fixture_scene
    city_T_scene = scene_frame_for(scene.city_T_ego[0])
    scene_T_city = T_inverse(city_T_scene)
    surface = GroundSurface(scene, scene_T_city)
    cfg = InitConfig(ground_spacing_m=1.0, ground_radius_m=8.0)
    seeds, cells = ground_seeds(surface, np.zeros((0, 2)), cfg)
    assert len(seeds) > 100
    np.testing.assert_allclose(seeds[:, :2], (cells + 0.5) * cfg.ground_spacing_m)  # an aligned grid
    # On the raster, each seed lies between the heights of the (valid) cells around it: bilinear.
    r = scene.ground_height
    xy_city = seeds[:, :2] + city_T_scene[:2, 3]
    p = r.s * (xy_city @ r.R.T + r.t) - 0.5
    c0, r0 = np.floor(p[:, 0]).astype(int), np.floor(p[:, 1]).astype(int)
    neigh = np.stack([r.heights[r0 + dr, c0 + dc].astype(float) for dr in (0, 1) for dc in (0, 1)], 1)
    ok = np.isfinite(neigh).all(1)
    assert ok.mean() > 0.9
    z_city = seeds[ok, 2] + city_T_scene[2, 3]
    assert np.all(z_city >= neigh[ok].min(1) - 1e-6) and np.all(z_city <= neigh[ok].max(1) + 1e-6)
    blocked = seeds[:10, :2]
    fewer, _ = ground_seeds(surface, blocked, cfg)
    assert len(fewer) <= len(seeds) - 10
    d = np.min(np.linalg.norm(fewer[:, None, :2] - blocked[None], axis=-1), axis=1)
    assert np.all(d > 0.3)
    assert math.isfinite(float(surface(np.zeros((1, 2)))[0]))


def test_ground_off_the_raster_continues_it_from_lidar_then_the_ego_plane(fixture_scene):
    """Real AV2 log: the raster covers the drivable area and a margin. Seeds just outside it must continue
    the raster's heights (from LiDAR ground returns) instead of jumping to the ego's height."""
    scene = fixture_scene
    city_T_scene = scene_frame_for(scene.city_T_ego[0])
    scene_T_city = T_inverse(city_T_scene)
    sweep = scene.sweep(scene.lidar_sweeps[0])
    scene_T_ego = scene_T_city @ scene.city_T_ego_at(int(scene.lidar_sweeps[0].timestamp_ns))
    lidar = sweep.xyz_ego @ scene_T_ego[:3, :3].T + scene_T_ego[:3, 3]
    with_lidar = GroundSurface(scene, scene_T_city, lidar)
    plane_only = GroundSurface(scene, scene_T_city)
    g = np.stack(np.meshgrid(np.arange(-40, 40, 0.5), np.arange(-40, 40, 0.5)), -1).reshape(-1, 2)
    on = np.isfinite(with_lidar.raster_height(g))
    assert 0.1 < on.mean() < 0.9
    from scipy.spatial import cKDTree

    d, i = cKDTree(g[on]).query(g[~on], k=1)
    edge = np.flatnonzero(~on)[d <= 0.75]  # just outside the raster's region
    inside = np.flatnonzero(on)[i[d <= 0.75]]
    step_lidar = np.abs(with_lidar(g[edge]) - with_lidar(g[inside]))
    assert np.median(step_lidar) < 0.1
    # LiDAR ground returns agree with the raster where both exist (the raster is the truth there).
    zl = with_lidar.lidar_cells[1]
    tree = with_lidar.lidar_cells[0]
    cells = tree.data[np.isfinite(zl)]
    zr = with_lidar.raster_height(cells)
    both = np.isfinite(zr)
    assert both.sum() > 50 and np.median(np.abs(zl[np.isfinite(zl)][both] - zr[both])) < 0.1
    # Without LiDAR the plane under the nearest pose takes over: finite everywhere.
    assert np.all(np.isfinite(plane_only(g)))


@pytest.mark.parametrize("threads", [1, 2])
def test_depth_targets_read_each_sweep_once_and_match_one_view_at_a_time(tmp_path, threads):
    import dataclasses

    import device_scenes as ds

    from nuav2.splat.train_views import lidar_depth_by_view, lidar_depth_samples
    from nuav2.splat.views import source_views

    scene = ds.tiny_scene(tmp_path)
    reads: list[int] = []

    def counted(ref):
        reads.append(ref.timestamp_ns)
        return scene.load_lidar(ref)

    counting = dataclasses.replace(scene, load_lidar=counted)
    views = source_views(scene, 1.0)
    scene_T_city = T_inverse(scene.city_T_ego_at(int(scene.sweep_timestamps_ns[0])))
    got = lidar_depth_by_view(counting, views, scene_T_city, threads=threads)
    assert len(reads) == len(set(reads)) == len(scene.lidar_sweeps)  # every sweep once, none twice
    assert len({v.channel for v in views}) == 7 and len(views) > len(reads)
    for v, uvz in zip(views, got, strict=True):
        np.testing.assert_array_equal(uvz, lidar_depth_samples(scene, v, scene_T_city))
    assert sum(len(u) > 100 for u in got) >= len(views) // 2


@pytest.mark.parametrize("road", [None, (0.3, 0.25, 0.2)])
def test_sky_texture_below_the_horizon_is_road_not_the_horizon_sky(road):
    """Bins below the horizon that no sky pixel reached take the road's colour when it is given (the
    sky shows through wherever the road is partly transparent); without it, the nearest row's sky."""
    from nuav2.splat.sky_init import sky_row_elevations, sky_texture_from_views

    h, w = 21, 31
    img = np.zeros((h, w, 3), np.float32)
    img[: h // 2] = [0.5, 0.7, 0.9]  # sky above the horizon row
    img[h // 2 :] = [0.3, 0.25, 0.2]
    view = _view(img, make_T(CAM_R_FORWARD_X, [0, 0, 0]))
    sky = np.zeros((h, w), bool)
    sky[: h // 2] = True
    tex = sky_texture_from_views([view], {0: sky}, np.eye(4), 32, 64, below_horizon_rgb=road)
    below = sky_row_elevations(32) < 0
    assert below.sum() == 6 and not below[:26].any()  # rows 26..31: -3.5 to -20 degrees
    np.testing.assert_allclose(tex[~below], np.broadcast_to([0.5, 0.7, 0.9], tex[~below].shape), atol=1e-6)
    want = [0.5, 0.7, 0.9] if road is None else road
    np.testing.assert_allclose(tex[below], np.broadcast_to(want, tex[below].shape), atol=1e-6)


def test_sky_rows_missing_near_the_horizon_take_sky_not_road():
    """Buildings hide the sky's lowest rows (an urban canyon): those rows, above the horizon, copy the
    nearest sky row, never the road below the horizon; with no sky pixel at all, the sky keeps the
    model's default colour above the horizon and the road's below."""
    from nuav2.splat.sky import SKY_INIT_RGB
    from nuav2.splat.sky_init import sky_row_elevations, sky_texture_from_views

    h, w = 21, 31
    img = np.full((h, w, 3), 0.3, np.float32)
    img[:4] = [0.5, 0.7, 0.9]  # sky only above ~ +20 deg: the rows down to the horizon are facades
    view = _view(img, make_T(CAM_R_FORWARD_X, [0, 0, 0]))
    sky = np.zeros((h, w), bool)
    sky[:4] = True
    road = (0.3, 0.25, 0.2)
    above = sky_row_elevations(32) >= 0
    tex = sky_texture_from_views([view], {0: sky}, np.eye(4), 32, 64, below_horizon_rgb=road)
    np.testing.assert_allclose(tex[above], np.broadcast_to([0.5, 0.7, 0.9], tex[above].shape), atol=1e-6)
    np.testing.assert_allclose(tex[~above], np.broadcast_to(road, tex[~above].shape), atol=1e-6)
    no_sky = sky_texture_from_views([view], {0: np.zeros((h, w), bool)}, np.eye(4), 32, 64,
                                    below_horizon_rgb=road)
    np.testing.assert_allclose(no_sky[above], np.broadcast_to(SKY_INIT_RGB, no_sky[above].shape), atol=1e-6)
    np.testing.assert_allclose(no_sky[~above], np.broadcast_to(road, no_sky[~above].shape), atol=1e-6)
    assert sky_texture_from_views([view], {0: np.zeros((h, w), bool)}, np.eye(4), 32, 64) is None
