"""Ground-truth renderer vs direct projection: paint, box corners, silhouettes, depth, any rig and pose."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from nuav2.geometry import T_inverse, make_T, transform_points
from nuav2.rig import CameraSpec, load_rig
from nuav2.synth import SynthConfig, build_world, render_view
from nuav2.synth.boxes import BoxSet, intersect_rays
from nuav2.synth.render import EGO_BODY, NEAR_Z, SUN_DIR
from nuav2.synth.road import ROAD_HALF

EMPTY = SynthConfig(seconds=0.5, n_parked=0, n_moving=0, n_pedestrians=0)
BUSY = SynthConfig(seconds=0.5)


@pytest.fixture(scope="module")
def empty_world():
    return build_world(21, EMPTY)


@pytest.fixture(scope="module")
def busy_world():
    return build_world(0, BUSY)


def look_at(world, eye_local, target_local) -> np.ndarray:
    """city_T_cam of an OpenCV camera (x right, y down, z forward) at ``eye`` looking at ``target``."""
    z = np.asarray(target_local, float) - eye_local
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return world.city_T_local @ make_T(np.column_stack([x, y, z]), eye_local)


def project(cam: CameraSpec, city_T_cam, points_local, world) -> tuple[np.ndarray, np.ndarray]:
    p_cam = transform_points(T_inverse(city_T_cam) @ world.city_T_local, points_local)
    uv = p_cam @ cam.K.T
    return uv[:, :2] / uv[:, 2:], p_cam[:, 2]


def pixel_rays_local(cam: CameraSpec, local_T_cam: np.ndarray) -> np.ndarray:
    """(H, W, 3) local-frame rays with camera z = 1 through every pixel centre."""
    u, v = np.meshgrid(np.arange(cam.width), np.arange(cam.height))
    rays = np.stack([(u - cam.K[0, 2]) / cam.K[0, 0], (v - cam.K[1, 2]) / cam.K[1, 1], np.ones(u.shape)], -1)
    return rays @ local_T_cam[:3, :3].T


def ground_depth(cam: CameraSpec, city_T_cam: np.ndarray, world) -> np.ndarray:
    """Analytic z-depth of the ground plane per pixel (inf where the ray does not reach it)."""
    local_T_cam = world.local_T_city @ city_T_cam
    dz = pixel_rays_local(cam, local_T_cam)[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -local_T_cam[2, 3] / dz
    return np.where(t > 0, t, np.inf)


def window(a: np.ndarray, uv: np.ndarray, r: int = 1) -> np.ndarray:
    u, v = int(round(uv[0])), int(round(uv[1]))
    return a[max(v - r, 0): v + r + 1, max(u - r, 0): u + r + 1]


def test_lane_paint_projects_onto_painted_pixels(empty_world):
    world = empty_world
    cam = load_rig("av2", scale=0.125).camera("ring_front_center")
    eye = np.array([30.0, -3.5, 1.7])
    city_T_cam = look_at(world, eye, [40.0, -3.5, 0.0])
    img, depth = render_view(world, cam, city_T_cam, world.timeline.t0_ns, with_depth=True)
    lum = img.astype(float).mean(axis=2)
    tested = 0
    for x in (34.0, 36.0, 38.0, 40.0, 42.0):
        paint = np.array([[x, -ROAD_HALF, 0.0], [x, -ROAD_HALF + 1.0, 0.0], [x, 0.12, 0.0]])
        uv, z = project(cam, city_T_cam, paint, world)
        inside = (uv[:, 0] > 2) & (uv[:, 0] < cam.width - 3) & (uv[:, 1] > 2) & (uv[:, 1] < cam.height - 3)
        if not inside.all():
            continue
        tested += 1
        # Solid white edge line: a bright, neutral pixel within 1 px of the projection.
        win = window(img, uv[0]).reshape(-1, 3).astype(float)
        assert np.any((win.min(axis=1) > 170) & (win.max(axis=1) - win.min(axis=1) < 40)), (x, win)
        assert np.min(np.abs(window(depth, uv[0]) - z[0])) < 0.02 * z[0]
        # One metre inside the lane: asphalt.
        assert window(lum, uv[1], 0).item() < 130
        # Left line of the double yellow centre line: yellow.
        win = window(img, uv[2]).reshape(-1, 3).astype(float)
        assert np.any(win[:, 0] - win[:, 2] > 60), (x, win)
    assert tested >= 2


def test_box_silhouette_and_corner_match_projection(busy_world):
    world = busy_world
    ts = world.timeline.t0_ns
    cam = load_rig("av2", scale=0.25).camera("ring_front_left")
    actors = world.actor_boxes_at(ts)
    car = next(i for i, a in enumerate(world.actors) if a.speed == 0.0 and a.category == "REGULAR_VEHICLE")
    centre = actors.center[car]
    toward_road = -np.sign(centre[:2]) * (np.abs(centre[:2]) > 5.0)  # the car stands in a parking strip
    eye = centre + np.array([*(6.0 * toward_road + [-3.0, 2.0]), 2.4 - centre[2]])
    city_T_cam = look_at(world, eye, centre)
    img, depth = render_view(world, cam, city_T_cam, ts, with_depth=True)

    corners = actors.subset(np.array([car])).corners()[0]
    uv, z = project(cam, city_T_cam, corners, world)
    assert np.all(z > 1.0)
    # The nearest top corner (where three visible faces meet) is drawn at the box's depth.
    top = np.flatnonzero(corners[:, 2] > centre[2])
    k = top[np.argmin(z[top])]
    assert np.min(np.abs(window(depth, uv[k]) - z[k])) < 0.03 * z[k]
    # Silhouette: the car's pixels are the convex hull of its projected corners, up to 1 px.
    hull = np.zeros(depth.shape, np.uint8)
    cv2.fillConvexPoly(hull, np.round(cv2.convexHull(uv.astype(np.float32))[:, 0] * 16).astype(np.int32), 1,
                       cv2.LINE_8, 4)
    car_mask = (depth < z.max() + 0.5) & (depth < ground_depth(cam, city_T_cam, world) - 1e-3)
    kernel = np.ones((3, 3), np.uint8)
    assert not np.any(car_mask & ~cv2.dilate(hull, kernel).astype(bool))
    assert not np.any(cv2.erode(hull, kernel).astype(bool) & ~car_mask)
    assert car_mask.sum() > 200
    # Top-face colour: the car colour, darkened for the roof, lit by the sun from above.
    top_centre = centre + [0.0, 0.0, actors.size[car, 2] / 2]
    uv_c, _ = project(cam, city_T_cam, top_centre[None], world)
    expected = np.array(world.actors[car].color) * 0.85 * (0.45 + 0.55 * SUN_DIR[2])
    np.testing.assert_allclose(window(img, uv_c[0], 0).reshape(3), expected, atol=1.0)


@pytest.mark.parametrize("seed", [0, 1])
def test_nuscenes_rig_renders_any_pose_with_sane_depth(busy_world, seed):
    world = busy_world
    rig = load_rig("nuscenes", scale=0.1)
    rng = np.random.default_rng(seed)
    for _ in range(2):
        yaw, pitch, roll = rng.uniform(-np.pi, np.pi), rng.uniform(-0.1, 0.1), rng.uniform(-0.05, 0.05)
        cy, sy, cp, sp = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch)
        cr, sr = np.cos(roll), np.sin(roll)
        R = (np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
             @ np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
             @ np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]]))
        # nuScenes ego origin is on the ground: ego z = ground height (+ a random bump).
        local_T_ego = make_T(R, [rng.uniform(-60, 60), rng.uniform(-5, 5), rng.uniform(0.0, 0.5)])
        city_T_ego = world.city_T_local @ local_T_ego
        for cam in rig.cameras:
            city_T_cam = city_T_ego @ cam.ego_T_cam
            img, depth = render_view(world, cam, city_T_cam, world.timeline.t0_ns, with_depth=True)
            assert img.shape == (cam.height, cam.width, 3) and img.dtype == np.uint8
            assert depth.shape == (cam.height, cam.width) and depth.dtype == np.float32
            assert not np.any(np.isnan(depth))
            finite = np.isfinite(depth)
            assert finite.any() and np.all(depth[finite] > NEAR_Z)
            # Sky (inf) only above the horizon; nothing is ever farther than the ground.
            dz = pixel_rays_local(cam, world.local_T_city @ city_T_cam)[..., 2]
            assert np.all(dz[~finite] >= -1e-9)
            assert np.all(depth <= ground_depth(cam, city_T_cam, world) * (1 + 1e-5) + 1e-5)


def test_rays_parallel_to_ground_and_extreme_views_give_no_nan(busy_world):
    world = busy_world
    ts = world.timeline.t0_ns
    cam = CameraSpec("probe", 64, 48, np.array([[40.0, 0, 31.5], [0, 40.0, 24.0], [0, 0, 1]]), np.eye(4))
    level = np.array([[0.0, 0, 1], [-1, 0, 0], [0, -1, 0]])  # local_R_cam looking +x, exactly level
    for eye, R in [((0.0, -3.5, 1.5), level),  # row 24 rays are exactly parallel to the ground
                   ((0.0, -3.5, 20.0), np.diag([1.0, -1.0, -1.0])),  # straight down
                   ((0.0, -3.5, 1.5), np.diag([1.0, 1.0, 1.0])),  # straight up
                   (tuple(world.buildings.center[0]), level),  # inside a building
                   ((0.0, -3.5, -2.0), level)]:  # under the ground
        city_T_cam = world.city_T_local @ make_T(R, eye)
        img, depth = render_view(world, cam, city_T_cam, ts, with_depth=True)
        assert not np.any(np.isnan(depth)) and img.dtype == np.uint8
        assert np.all(depth > 0)
    # Level camera: the horizon row never hits the ground, the row below always hits something.
    level_pose = world.city_T_local @ make_T(level, (0.0, -3.5, 1.5))
    img, depth = render_view(world, cam, level_pose, ts, with_depth=True)
    assert np.all(np.isfinite(depth[25:]))
    # Straight down from 20 m: the ground at depth 20 unless a box is nearer.
    down_pose = world.city_T_local @ make_T(np.diag([1.0, -1, -1]), (0.0, -3.5, 20.0))
    _, depth = render_view(world, cam, down_pose, ts, with_depth=True)
    assert np.all(depth <= 20.0 + 1e-4) and np.mean(np.abs(depth - 20.0) < 1e-4) > 0.5
    # Inside a building every ray ends on a wall, floor or roof of that building.
    b = world.buildings
    _, depth = render_view(world, cam, world.city_T_local @ make_T(level, b.center[0]), ts, with_depth=True)
    assert np.all(np.isfinite(depth)) and depth.max() <= np.linalg.norm(b.size[0]) + 1e-6


def test_wall_crossing_the_near_plane_is_clipped_exactly(busy_world):
    world = busy_world
    b = world.buildings.subset(np.array([0]))
    c, half = b.center[0], b.size[0] / 2
    # Eye 0.4 m in front of the wall facing the road (smallest |y| face), looking along it at 30 degrees.
    side = -np.sign(c[1])
    wall_y = c[1] + side * half[1]
    eye = np.array([c[0], wall_y + side * 0.4, 2.0])
    along = np.array([np.cos(np.deg2rad(30)), -side * np.sin(np.deg2rad(30)), 0.0])
    city_T_cam = look_at(world, eye, eye + along)
    cam = CameraSpec("probe", 96, 64, np.array([[50.0, 0, 47.5], [0, 50.0, 31.5], [0, 0, 1]]), np.eye(4))
    _, depth = render_view(world, cam, city_T_cam, world.timeline.t0_ns, with_depth=True)
    rays = pixel_rays_local(cam, world.local_T_city @ city_T_cam)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_wall = (wall_y - eye[1]) / rays[..., 1]
    hit = eye + t_wall[..., None] * rays
    on_wall = ((t_wall > NEAR_Z) & (np.abs(hit[..., 0] - c[0]) < half[0] - 0.01) & (hit[..., 2] > 0.01)
               & (hit[..., 2] < 2 * half[2] - 0.01))
    assert on_wall.sum() > 100
    np.testing.assert_allclose(depth[on_wall], t_wall[on_wall], rtol=1e-5)


def test_ray_box_kernel_matches_face_plane_oracle():
    """The slab kernel against an independent method: intersect all six face planes, keep hits
    inside the face rectangle, take the nearest beyond t_min (also right for rays starting inside)."""
    rng = np.random.default_rng(3)
    n = 12
    boxes = BoxSet(rng.uniform(-10, 10, (n, 3)), rng.uniform(-np.pi, np.pi, n), rng.uniform(0.5, 4.0, (n, 3)),
                   np.zeros((n, 3), np.float32), np.zeros(n, np.int8), np.zeros(n, np.uint8))
    boxes.yaw[:3] = 0.0  # axis-aligned boxes, so the parallel rays below are exactly parallel to faces
    origin = boxes.center[5] + 0.1  # start inside box 5 for some rays
    dirs = rng.normal(size=(3000, 3))
    dirs[:50, 2] = 0.0
    dirs[50:60] = [1.0, 0.0, 0.0]
    t_min = 1e-3
    hits = intersect_rays(origin, dirs, boxes, t_min=t_min)
    best_t = np.full(len(dirs), np.inf)
    best_box = np.full(len(dirs), -1)
    best_face = np.full(len(dirs), -1)
    R = boxes.rotations
    for i in range(n):
        o_b = R[i].T @ (origin - boxes.center[i])
        d_b = dirs @ R[i]
        half = boxes.size[i] / 2
        for axis in range(3):
            for sign in (-1.0, 1.0):
                with np.errstate(divide="ignore", invalid="ignore"):  # parallel rays: inf or nan, no hit
                    t = (sign * half[axis] - o_b[axis]) / d_b[:, axis]
                    p = o_b + t[:, None] * d_b
                others = [a for a in range(3) if a != axis]
                ok = (t > t_min) & np.all(np.abs(p[:, others]) <= half[others] + 1e-9, axis=1)
                better = ok & (t < best_t)
                best_t[better], best_box[better], best_face[better] = t[better], i, 2 * axis + (sign > 0)
    assert not np.any(np.isnan(hits.t))
    assert np.isfinite(best_t).sum() > 500 and np.sum(hits.box == 5) > 100
    np.testing.assert_array_equal(np.isfinite(hits.t), np.isfinite(best_t))
    np.testing.assert_allclose(hits.t, best_t, rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(hits.box, best_box)
    np.testing.assert_array_equal(hits.face, best_face)


def test_ego_mask_is_drawn_with_zero_depth(busy_world):
    world = busy_world
    cam = load_rig("av2", scale=0.125).camera("ring_front_center")
    ts = int(world.timeline.images_ns["ring_front_center"][0])
    img, depth = render_view(world, cam, world.city_T_ego_at(ts) @ cam.ego_T_cam, ts, with_depth=True)
    mask = cam.ego_mask()
    assert 0.05 < mask.mean() < 0.3
    assert np.all(depth[mask] == 0.0) and np.all(depth[~mask] > 0.0)
    body = img[mask].astype(float)
    assert np.all(np.abs(body - EGO_BODY).max(axis=1) <= 0.2 * EGO_BODY.max() + 1)


def test_region_labels_agree_with_depth_and_actor_boxes(busy_world):
    """Labels say sky exactly where depth is inf, ego exactly under the mask, ground where the
    depth equals the flat ground's, and objects on the pixels of annotated actors."""
    from nuav2.synth.render import LABEL_EGO, LABEL_GROUND, LABEL_OBJECT, LABEL_SKY, LABEL_STATIC

    world = busy_world
    cam = load_rig("av2", scale=0.125).camera("ring_front_center")
    ts = int(world.timeline.images_ns["ring_front_center"][0])
    city_T_cam = world.city_T_ego_at(ts) @ cam.ego_T_cam
    img, depth, labels = render_view(world, cam, city_T_cam, ts, with_depth=True, with_labels=True)
    np.testing.assert_array_equal(img, render_view(world, cam, city_T_cam, ts))
    assert labels.shape == depth.shape and labels.dtype == np.uint8
    np.testing.assert_array_equal(labels == LABEL_SKY, np.isinf(depth))
    np.testing.assert_array_equal(labels == LABEL_EGO, cam.ego_mask())
    ground = labels == LABEL_GROUND
    assert ground.mean() > 0.2
    gd = ground_depth(cam, city_T_cam, world)
    np.testing.assert_allclose(depth[ground], gd[ground], rtol=1e-4)
    hit = (labels == LABEL_OBJECT) | (labels == LABEL_STATIC)
    assert np.all(depth[hit] < gd[hit] * (1 + 1e-5) + 1e-5)
    assert (labels == LABEL_OBJECT).any() or (labels == LABEL_STATIC).any()
