"""Depth proxy: ground (plane + raster), lidar disks, ray/box slabs, their z-buffer, and round trips."""

from __future__ import annotations

import numpy as np
import pytest
from warp_scenes import camera, city_T_cam, render_plane_world

from nuav2.geometry import T_inverse, make_T, transform_points
from nuav2.scene import GroundHeightRaster
from nuav2.terrain import bilinear_height
from nuav2.warp.depth_proxy import (
    NO_BOX,
    GroundSurface,
    ProxyConfig,
    ProxyGeometry,
    box_depth,
    close_holes,
    ground_depth,
    lidar_depth,
    pixel_rays_cam,
    ray_box_t,
    render_depth_proxy,
)
from nuav2.warp.tracks import BoxTracks  # noqa: F401  (import check: module loads)

CFG = ProxyConfig()
GROUND = GroundSurface.horizontal(0.0)


def test_ground_plane_depth_round_trips_to_the_plane():
    cam = camera()
    T = city_T_cam(1000.0, -2000.0, 51.5, yaw=0.4, pitch_down=0.2)  # city-scale offsets, ground at z = 50
    d = ground_depth(cam, T, GroundSurface.horizontal(50.0), CFG)
    assert not np.any(np.isnan(d))
    hit = np.isfinite(d)
    assert hit.sum() > 0.3 * d.size and (~hit).sum() > 0  # horizon inside the image
    pts = T[:3, 3] + d.reshape(-1)[hit.reshape(-1), None] * (
        pixel_rays_cam(cam).reshape(-1, 3)[hit.reshape(-1)] @ T[:3, :3].T)
    np.testing.assert_allclose(pts[:, 2], 50.0, atol=1e-9)


def test_exact_principal_ray_depth():
    cam = camera(width=65, height=49)  # odd size: pixel (32, 24) is the principal point
    T = city_T_cam(0.0, 0.0, 2.0, pitch_down=0.3)
    d = ground_depth(cam, T, GroundSurface.horizontal(0.0), CFG)
    assert np.isclose(d[24, 32], 2.0 / np.sin(0.3), rtol=1e-12)


def test_rays_parallel_or_upward_give_inf_not_nan():
    cam = camera(width=65, height=49)
    T = city_T_cam(0.0, 0.0, 1.5, pitch_down=0.0)  # optical axis parallel to the ground
    with np.errstate(all="raise"):
        d = ground_depth(cam, T, GroundSurface.horizontal(0.0), CFG)
    assert not np.any(np.isnan(d))
    assert np.all(np.isinf(d[:25]))  # rows at and above the principal row never meet the ground
    assert np.all(np.isfinite(d[30:]))
    raster = GroundHeightRaster(np.zeros((10, 10)), np.eye(2), np.zeros(2), 1.0)
    d2 = ground_depth(cam, T, GroundSurface.horizontal(0.0, raster), CFG)
    assert not np.any(np.isnan(d2)) and np.all(np.isinf(d2[:25]))
    # A camera below the ground plane looking down never hits it either.
    d3 = ground_depth(cam, city_T_cam(0.0, 0.0, -1.0, pitch_down=0.5), GroundSurface.horizontal(0.0), CFG)
    assert np.all(np.isinf(d3))


def test_max_depth_cuts_the_far_ground():
    cam = camera(width=65, height=49)
    T = city_T_cam(0.0, 0.0, 1.5, pitch_down=0.0)
    d = ground_depth(cam, T, GroundSurface.horizontal(0.0), ProxyConfig(max_depth_m=40.0))
    assert np.nanmax(d[np.isfinite(d)]) <= 40.0
    # Row 26 is 2 px below the principal row: z = 1.5 * f / 2 = 37.5 m (kept); row 25 is 75 m (cut).
    assert np.isclose(d[26, 32], 37.5) and np.isinf(d[25, 32])


def test_raster_heights_replace_the_plane_where_known():
    heights = np.full((400, 400), np.nan, np.float32)
    heights[:, 200:] = 0.5  # x >= 0 (cells of 0.25 m, origin at -50 m): a 0.5 m step up
    raster = GroundHeightRaster(heights, np.eye(2), np.array([50.0, 50.0]), 4.0)
    ground = GroundSurface.horizontal(0.0, raster)
    cam = camera(width=80, height=60, f=40.0)
    T = city_T_cam(-10.0, 0.0, 3.0, yaw=0.0, pitch_down=0.35)
    d = ground_depth(cam, T, ground, CFG)
    pts = T[:3, 3] + d.reshape(-1, 1) * (pixel_rays_cam(cam).reshape(-1, 3) @ T[:3, :3].T)
    ok = np.isfinite(d.reshape(-1))
    h = raster.height_at(pts[ok, :2])
    expect = np.where(np.isfinite(h), h, 0.0)
    # A ray ends on the raster height under its own hit, or on the step's riser (within a cell of x = 0).
    good = np.abs(pts[ok, 2] - expect) < 1e-9
    on_riser = (np.abs(pts[ok, 0]) < 0.26) & (pts[ok, 2] > -1e-9) & (pts[ok, 2] < 0.5 + 1e-9)
    assert np.all(good | on_riser) and good.mean() > 0.9
    assert np.any(pts[ok, 2] > 0.4) and np.any(pts[ok, 2] < 0.1)


def test_compiled_ground_height_matches_the_terrain_module_and_falls_back_to_the_plane():
    rng = np.random.default_rng(5)
    heights = rng.normal(0.0, 0.3, (40, 60)).astype(np.float32)
    heights[10:15, 20:30] = np.nan  # a hole inside the raster
    c, s_ = np.cos(0.3), np.sin(0.3)
    raster = GroundHeightRaster(heights, np.array([[c, s_], [-s_, c]]), np.array([5.0, 3.0]), 3.0)
    ground = GroundSurface(np.array([0.1, -0.05, 1.0]) / np.linalg.norm([0.1, -0.05, 1.0]), 0.4, raster)
    xy = rng.uniform(-15.0, 30.0, (20000, 2))  # inside, on the hole and far off the raster
    got = ground.height(xy)
    expect = bilinear_height(raster, xy)
    miss = ~np.isfinite(expect)
    assert 0.1 < miss.mean() < 0.9
    expect[miss] = ground.plane_height(xy[miss])
    assert np.all(np.isfinite(got))
    np.testing.assert_allclose(got, expect, atol=1e-9)


def test_ground_depth_predicted_in_blocks_matches_solving_every_ray_on_hills():
    x0, res = -60.0, 0.3
    yy, xx = np.mgrid[0:400, 0:400]
    x, y = x0 + (xx + 0.5) * res, x0 + (yy + 0.5) * res
    heights = (1.5 * np.sin(x / 9.0) * np.cos(y / 13.0) + 0.04 * x).astype(np.float32)  # hills on a grade
    heights[180:200, 250:280] = np.nan  # a hole: the plane shows through
    raster = GroundHeightRaster(heights, np.eye(2), np.array([-x0, -x0]), 1 / res)
    ground = GroundSurface.horizontal(0.0, raster)
    cam = camera(width=97, height=61, f=60.0)  # sizes that are not multiples of the block
    for yaw, pitch in ((0.0, 0.2), (2.0, 0.05), (-1.0, 0.4)):
        T = city_T_cam(0.0, 0.0, 2.0, yaw=yaw, pitch_down=pitch)
        d = ground_depth(cam, T, ground, CFG)
        rays = pixel_rays_cam(cam).reshape(-1, 3) @ T[:3, :3].T
        exact = ground.intersect(T[:3, 3], rays, 40, tol_m=1e-6).reshape(d.shape)  # the oracle
        per_ray = ground.intersect(T[:3, 3], rays, CFG.ground_iterations).reshape(d.shape)  # no prediction
        for t in (exact, per_ray):
            t[(t < CFG.near_m) | (t > CFG.max_depth_m)] = np.inf
        both = np.isfinite(d) & np.isfinite(exact)
        assert both.mean() > 0.3 and (np.isfinite(d) != np.isfinite(exact)).mean() < 0.002
        rel = np.abs(d[both] - exact[both]) / exact[both]
        rel_per_ray = np.abs(per_ray[both] - exact[both]) / exact[both]
        # as close to the exact hit as solving every ray (0.4 mm at 10 m in the median)
        assert np.median(rel) < 1e-4 and np.quantile(rel, 0.99) < 0.01
        assert np.quantile(rel, 0.99) <= 1.05 * np.quantile(rel_per_ray, 0.99) + 1e-4


def test_march_skipping_samples_above_the_raster_top_changes_no_bit():
    """The ray march steps over samples above both the raster's top and the plane without a height
    lookup: the hits must be bit for bit those of the full march (h_top = inf never skips)."""
    from nuav2.warp._kernels import MARCH_T0, _march_safe_t, ground_intersect_kernel

    x0, res = -60.0, 0.3
    yy, xx = np.mgrid[0:400, 0:400]
    x, y = x0 + (xx + 0.5) * res, x0 + (yy + 0.5) * res
    heights = (1.5 * np.sin(x / 9.0) * np.cos(y / 13.0) + 0.04 * x).astype(np.float32)
    heights[180:200, 250:280] = np.nan
    raster = GroundHeightRaster(heights, np.eye(2), np.array([-x0, -x0]), 1 / res)
    assert raster.top == np.nanmax(heights)
    n = np.array([0.03, -0.02, 1.0]) / np.linalg.norm([0.03, -0.02, 1.0])  # the plane shows off the raster
    ground = GroundSurface(n, 0.2, raster)
    rng = np.random.default_rng(11)
    dirs = rng.normal(size=(6000, 3))
    dirs[:, 2] = -np.abs(dirs[:, 2]) * rng.choice([0.02, 0.2, 1.0], 6000)  # grazing to steep
    skipped = 0
    for origin in ([0.0, 0.0, 4.0], [30.0, -20.0, 6.0], [-50.0, 40.0, 0.5]):  # the last sits below the top
        origin = np.array(origin)
        args = ground.ray_kernel_args()
        for iterations in (1, 3):
            fast, full = np.empty(len(dirs)), np.empty(len(dirs))
            ground_intersect_kernel(origin, dirs, *args, iterations, 1e4, 1e-3, fast)
            ground_intersect_kernel(origin, dirs, *args[:-1], np.inf, iterations, 1e4, 1e-3, full)
            np.testing.assert_array_equal(fast.view(np.int64), full.view(np.int64))
            assert np.isfinite(fast).mean() > 0.5
        skipped += sum(_march_safe_t(*origin, *d, n, 0.2, raster.top) > MARCH_T0 for d in dirs[:500])
    assert skipped > 300  # the skip is taken (from the two origins above the top)


def test_raster_refinement_converges_on_a_gentle_slope():
    x0, res = -100.0, 0.1
    cols = np.arange(2000)
    heights = np.tile((0.03 * (x0 + (cols + 0.5) * res))[None, :], (50, 1))
    raster = GroundHeightRaster(heights, np.eye(2), np.array([-x0, 2.5]), 1 / res)
    ground = GroundSurface.horizontal(0.0, raster)
    cam = camera(width=40, height=30, f=30.0)
    T = city_T_cam(0.0, 0.0, 1.8, pitch_down=0.25)
    d = ground_depth(cam, T, ground, ProxyConfig(ground_iterations=6))
    pts = T[:3, 3] + d.reshape(-1, 1) * (pixel_rays_cam(cam).reshape(-1, 3) @ T[:3, :3].T)
    ok = np.isfinite(d.reshape(-1)) & (np.abs(pts[:, 1]) < 2.4)
    assert ok.sum() > 100
    np.testing.assert_allclose(pts[ok, 2], 0.03 * pts[ok, 0], atol=0.02)  # the solver tolerance


def test_ground_under_ego_follows_its_tilt():
    R = np.array([[np.cos(0.1), 0, np.sin(0.1)], [0, 1, 0], [-np.sin(0.1), 0, np.cos(0.1)]])
    city_T_ego = make_T(R, [5.0, 3.0, 100.0])
    g = GroundSurface.under_ego(city_T_ego, 0.32)
    foot = transform_points(city_T_ego, [[0.0, 0.0, -0.32], [10.0, 2.0, -0.32]])
    np.testing.assert_allclose(foot @ g.normal, g.offset, atol=1e-9)


def test_ray_box_slabs_against_surface_and_marching_oracles():
    rng = np.random.default_rng(3)
    half = np.array([2.0, 1.0, 0.75])
    n_hits = 0
    for _ in range(5):
        o = rng.uniform(-6, 6, 3)
        d = rng.normal(size=(400, 3))
        d[:40, 0] = 0.0  # axis-parallel rays
        d[40:60, :2] = 0.0
        t = ray_box_t(o, d, half, near=0.0)
        assert not np.any(np.isnan(t))
        hit = np.isfinite(t)
        n_hits += hit.sum()
        p = o + t[hit, None] * d[hit]
        # A hit lies on the surface (or is the origin itself when it starts inside) ...
        on_surface = np.isclose(np.max(np.abs(p) / half, axis=1), 1.0, atol=1e-9)
        assert np.all(on_surface | (t[hit] == 0.0))
        # ... and is the first one: a step back along the ray is outside.
        back = o + (t[hit, None] - 1e-6) * d[hit]
        assert not np.any(np.all(np.abs(back) < half * (1 - 1e-9), axis=1) & (t[hit] > 0))
        # A miss never passes through the box (marching oracle).
        ts = np.linspace(0.0, 40.0, 4001)
        pm = o[None, None] + ts[None, :, None] * d[~hit, None, :]
        assert not np.any(np.all(np.abs(pm) < half, axis=2))
    assert n_hits > 50


def test_ray_box_origin_on_a_face_and_parallel_is_not_nan():
    half = np.array([1.0, 1.0, 1.0])
    o = np.array([1.0, 0.0, -5.0])  # on the x = +1 face plane
    d = np.array([[0.0, 0.0, 1.0], [0.0, 1e-15, 1.0], [1.0, 0.0, 0.0]])
    with np.errstate(all="raise"):
        t = ray_box_t(o, d, half, near=0.0)
    assert np.isclose(t[0], 4.0) and np.isclose(t[1], 4.0) and np.isinf(t[2])
    # Starting inside: the hit is at the near distance.
    assert ray_box_t(np.zeros(3), d[:1], half, near=0.1)[0] == pytest.approx(0.1)


def test_box_depth_matches_the_analytic_renderer_and_indexes_boxes():
    cam = camera(width=80, height=60)
    T = city_T_cam(0.0, 0.0, 1.5, pitch_down=0.05)
    boxes = [make_T(np.eye(3), [12.0, 1.0, 0.8]), make_T(np.eye(3), [20.0, -2.0, 0.8])]
    sizes = np.array([[4.0, 2.0, 1.6], [4.0, 2.0, 1.6]])
    d, idx = box_depth(cam, T, np.stack(boxes), sizes, CFG)
    _, d_ref = render_plane_world(cam, T, [(boxes[0], sizes[0], (1, 0, 0)), (boxes[1], sizes[1], (0, 1, 0))],
                                  ground_z=None)
    hit = np.isfinite(d_ref)
    assert np.array_equal(np.isfinite(d), hit)
    np.testing.assert_allclose(d[hit], d_ref[hit], rtol=1e-9)
    assert set(np.unique(idx[hit])) == {0, 1} and np.all(idx[~hit] == NO_BOX)
    # Front face of box 0 is the plane x = 10 (camera z = 10 along the optical axis up to the pitch).
    assert np.isclose(d[idx == 0].min(), 10.0, rtol=0.01)


def test_box_straddling_the_camera_plane_is_clipped_not_lost():
    cam = camera(width=40, height=30)
    T = city_T_cam(0.0, 0.0, 1.0)
    box = make_T(np.eye(3), [0.5, 0.0, 1.0])[None]  # camera inside a 4 m box reaching behind it
    d, idx = box_depth(cam, T, box, np.array([[4.0, 4.0, 4.0]]), CFG)
    assert np.all(d == CFG.near_m) and np.all(idx == 0)
    # A box wholly behind the camera does not appear.
    d2, _ = box_depth(cam, T, make_T(np.eye(3), [-10.0, 0.0, 1.0])[None], np.array([[2.0, 2.0, 2.0]]), CFG)
    assert np.all(np.isinf(d2))


def test_lidar_disks_keep_the_nearest_point_and_skip_points_behind():
    cam = camera(width=64, height=48)
    T = city_T_cam(0.0, 0.0, 0.0)
    cam_T_city = T_inverse(T)
    # Two points on the optical axis (cam z 10 and 5) and one behind the camera.
    pts_cam = np.array([[0.0, 0.0, 10.0], [0.0, 0.0, 5.0], [0.0, 0.0, -3.0]])
    pts_city = transform_points(T, pts_cam)
    np.testing.assert_allclose(transform_points(cam_T_city, pts_city), pts_cam, atol=1e-12)
    cfg = ProxyConfig(fill_px=0)
    d = lidar_depth(cam, T, pts_city, np.array([0.2, 0.05, 1.0]), cfg)
    cy, cx = 23.5, 31.5
    yy, xx = np.mgrid[:48, :64]
    r = np.hypot(xx - cx, yy - cy)
    # Far point: radius 50 * 0.2 / 10 = 1 px; near point: 50 * 0.05 / 5 = 0.5 -> clipped to 0.75 px.
    assert np.all(d[r <= 0.75] == 5.0)
    assert np.all(d[(r > 0.75) & (r <= 1.0)] == 10.0)
    assert np.all(np.isinf(d[r > 1.0]))
    assert np.all(np.isinf(lidar_depth(cam, T, np.zeros((0, 3)), np.zeros(0), cfg)))


def test_hole_closing_fills_small_gaps_only():
    d = np.full((40, 40), np.inf)
    d[10:30, 10:30] = 8.0
    d[18:21, 18:21] = np.inf  # small hole in a surface
    d[0:40, 35] = 20.0  # a thin isolated line leaves the background empty around it
    out = close_holes(d, 5)
    assert np.all(out[18:21, 18:21] == pytest.approx(8.0, rel=1e-6))
    assert np.all(np.isinf(out[:, :8]))  # open background stays open
    assert np.isinf(out[5, 5]) and out[15, 15] == 8.0
    assert not np.any(np.isnan(out))
    assert np.array_equal(close_holes(np.full((5, 5), np.inf), 5), np.full((5, 5), np.inf))


def test_render_depth_proxy_zbuffer_and_point_round_trip():
    cam = camera(width=64, height=48)
    T = city_T_cam(100.0, 200.0, 31.5, yaw=0.3, pitch_down=0.1)
    box = make_T(np.eye(3), [100.0 + 10 * np.cos(0.3), 200.0 + 10 * np.sin(0.3), 30.8])
    geom = ProxyGeometry(GroundSurface.horizontal(30.0), np.zeros((0, 3)), np.zeros(0), box[None],
                         np.array([[2.0, 2.0, 1.6]]))
    proxy = render_depth_proxy(cam, T, geom)
    assert np.any(proxy.box_index == 0) and np.any(proxy.box_index == NO_BOX)
    pts, finite = proxy.points_city()
    ground = finite & (proxy.box_index.reshape(-1) == NO_BOX)
    np.testing.assert_allclose(pts[ground, 2], 30.0, atol=1e-8)
    # Project the points back: they land on their own pixel centres at their own depth.
    p_cam = transform_points(T_inverse(T), pts[finite])
    u = cam.K[0, 0] * p_cam[:, 0] / p_cam[:, 2] + cam.K[0, 2]
    v = cam.K[1, 1] * p_cam[:, 1] / p_cam[:, 2] + cam.K[1, 2]
    vv, uu = np.divmod(np.flatnonzero(finite), cam.width)
    np.testing.assert_allclose(u, uu, atol=1e-6)
    np.testing.assert_allclose(v, vv, atol=1e-6)
    np.testing.assert_allclose(p_cam[:, 2], proxy.depth.reshape(-1)[finite], rtol=1e-12)
    inv = proxy.inverse_depth()
    assert inv.dtype == np.float32 and np.all(inv[~np.isfinite(proxy.depth)] == 0)
    assert not np.any(np.isnan(inv))


def test_empty_geometry_gives_all_infinity():
    cam = camera(width=16, height=12)
    proxy = render_depth_proxy(cam, city_T_cam(0, 0, 1), ProxyGeometry.empty())
    assert np.all(np.isinf(proxy.depth)) and np.all(proxy.box_index == NO_BOX)
    with pytest.raises(ValueError, match="finite 4x4"):
        render_depth_proxy(cam, np.full((4, 4), np.nan), ProxyGeometry.empty())


def test_box_pixels_are_kept_only_where_the_actor_points_show_a_surface():
    """Two boxes on the ground: box 0's actor points fill only its upper half (a rounded body: the road under
    it is visible), box 1 has no points (far, occluded) and is kept whole."""
    cam = camera(width=80, height=60)
    T = city_T_cam(0.0, 0.0, 1.5, pitch_down=0.05)
    boxes = np.stack([make_T(np.eye(3), [12.0, 1.5, 0.8]), make_T(np.eye(3), [20.0, -3.0, 0.8])])
    sizes = np.array([[4.0, 2.0, 1.6], [4.0, 2.0, 1.6]])
    yy, zz = np.meshgrid(np.linspace(-1.0, 1.0, 41), np.linspace(0.0, 0.8, 17))
    face = np.column_stack([np.full(yy.size, -2.0), yy.ravel(), zz.ravel()])  # box 0's face, upper half
    whole = render_depth_proxy(cam, T, ProxyGeometry(GROUND, np.zeros((0, 3)), np.zeros(0), boxes, sizes))
    checked = render_depth_proxy(cam, T, ProxyGeometry(GROUND, np.zeros((0, 3)), np.zeros(0), boxes, sizes,
                                                       (face, np.zeros((0, 3)))))  # box-frame points
    lost = (whole.box_index == 0) & (checked.box_index != 0)
    kept = checked.box_index == 0
    assert kept.sum() > 30 and lost.sum() > 15  # (of 82 box pixels at this size)
    # The lost pixels are the lower half of the box's face: they now see the ground behind the box.
    rows_kept, rows_lost = np.nonzero(kept)[0], np.nonzero(lost)[0]
    assert rows_lost.min() > np.median(rows_kept)
    assert np.all(checked.depth[lost] > whole.depth[lost])
    np.testing.assert_array_equal(checked.box_index == 1, whole.box_index == 1)  # no points: kept whole
