"""Each realism factor does what it claims: relief and kerbs, layouts and manoeuvres, content that
is not its box, moving shadows and a structured sky, camera effects, lidar noise, label noise."""

from __future__ import annotations

import numpy as np
import pytest
import shapely
from shapely.geometry import LineString

from nuav2.rig import load_rig
from nuav2.synth import LAYOUTS, SynthConfig, build_world, cast_sweep
from nuav2.synth import polyline as pl
from nuav2.synth.boxes import BoxSet, intersect_rays
from nuav2.synth.camera_effects import CameraEffects
from nuav2.synth.layouts import build_plan, draw_params, plan_layout
from nuav2.synth.light import in_shadow, shadow_grid, sky_color
from nuav2.synth.log_writer import annotation_rows, stored_xyz
from nuav2.synth.motion import ego_motion, turn_kind
from nuav2.synth.terrain import CROSS_FALL, KERB_H
from nuav2.synth.world import EGO_ORIGIN_HEIGHT_M

SMALL = dict(seconds=1.0, map_margin_m=20.0, texture_res_m=0.1, lidar_azimuth_steps=256)


@pytest.fixture(scope="module")
def medium():
    return build_world(1, SynthConfig.for_preset("medium", **SMALL))


@pytest.fixture(scope="module")
def hard():
    return build_world(3, SynthConfig.for_preset("hard", **SMALL))


def test_relief_grades_crossfall_and_kerb_step(medium):
    t = medium.terrain
    road_pts = np.concatenate([pl.resample(0.5 * (ln.left + ln.right), 60) for ln in medium.map_layout.lanes])
    grade = np.linalg.norm(t.normal(road_pts)[:, :2], axis=1)
    assert 0.02 < grade.max() <= 0.09  # grades up to about 8 % (plus the 2 % cross-fall)
    # Crests and sags: the profile along a road's line through the world bends both ways.
    road = max(medium.plan.roads, key=lambda r: r.length)
    u = pl.tangents(road.centre)[0]
    reach = -t.meta[0] - 45.0  # inside the raster, short of the border taper
    line = np.outer(np.arange(-reach, reach, 2.0), u) + road.centre[0] - (road.centre[0] @ u) * u
    bend = np.diff(t.relief(line), 2)
    assert bend.max() > 1e-4 and bend.min() < -1e-4
    s = np.arange(0.0, road.length, 2.0)
    # Cross-fall: the crown is a ridge 2 % each way (second lateral difference -2 * 0.02 * d).
    d = 1.5
    p = pl.at(road.centre, s[5:-5])
    heading = pl.heading_at(road.centre, s[5:-5])
    n = np.column_stack([-np.sin(heading), np.cos(heading)])
    second = t.relief(p + d * n) + t.relief(p - d * n) - 2 * t.relief(p)
    assert np.mean(second) == pytest.approx(-2 * CROSS_FALL * d, abs=0.015)
    # Kerb: the sidewalk stands a kerb height above the gutter, right at the drivable boundary.
    drivable = medium.world_layout.drivable_union()
    ring = np.asarray(max(getattr(drivable, "geoms", [drivable]), key=lambda g: g.area).exterior.coords)
    q = ring[:-1] + 0.5 * (ring[1:] - ring[:-1])
    out = np.column_stack([(ring[1:] - ring[:-1])[:, 1], -(ring[1:] - ring[:-1])[:, 0]])
    out /= np.linalg.norm(out, axis=1, keepdims=True)
    if shapely.Polygon(ring).exterior.is_ccw is False:
        out = -out
    kerb = lambda x: t.height(x) - t.relief(x)  # noqa: E731
    step = kerb(q + 0.15 * out) - kerb(q - 0.15 * out)
    assert np.median(step) == pytest.approx(KERB_H, abs=1e-9)


def test_terrain_ray_hits_are_the_first_surface_crossing(medium):
    """Oracle: the first sign change of z - h along 20k samples per ray."""
    t = medium.terrain
    rng = np.random.default_rng(5)
    origin = np.array([3.0, -5.0, t.height(np.array([[3.0, -5.0]]))[0] + 1.7])
    dirs = rng.normal(size=(150, 3))
    dirs[:, 2] = -np.abs(dirs[:, 2]) * 0.25
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    hit = t.intersect(origin, dirs, 0.05, 80.0)
    ts = np.linspace(0.05, 80.0, 20001)
    for j in range(len(dirs)):
        p = origin + ts[:, None] * dirs[j]
        below = np.flatnonzero(p[:, 2] - t.height(p[:, :2]) <= 0)
        if len(below) == 0:
            assert not np.isfinite(hit[j]) or hit[j] > 80.0 - 0.01
            continue
        assert ts[below[0] - 1] - 1e-6 <= hit[j] <= ts[below[0]] + 1e-6, j
        q = origin + hit[j] * dirs[j]
        assert abs(q[2] - t.height(q[None, :2])[0]) < 1e-5


@pytest.mark.parametrize("name", LAYOUTS)
def test_layout_lane_graphs(name):
    params = draw_params(name, np.random.default_rng(4))
    layout = plan_layout(build_plan(name, 90.0, params))
    by_id = {ln.id: ln for ln in layout.lanes}
    area = layout.drivable_union().buffer(1e-6)
    for ln in layout.lanes:
        assert np.linalg.norm(ln.left[0] - ln.right[0]) == pytest.approx(3.5, abs=1e-6)
        for s in ln.successors:
            np.testing.assert_allclose(ln.left[-1], by_id[s].left[0], atol=1e-6)
            np.testing.assert_allclose(ln.right[-1], by_id[s].right[0], atol=1e-6)
            assert ln.id in by_id[s].predecessors
        assert area.contains(LineString(0.5 * (pl.resample(ln.left, 20) + pl.resample(ln.right, 20))))
    turns = {turn_kind(ln) for ln in layout.lanes if ln.is_intersection}
    if name in ("four_way", "t_junction", "y_junction"):
        assert turns == {"left", "right", "straight"}
    if name == "arterial":
        assert layout.drivable_union().geom_type == "MultiPolygon"  # the raised median splits it
    if name == "curved":
        c = 0.5 * (layout.lanes[0].left + layout.lanes[0].right)
        road = build_plan(name, 90.0, params).roads[0].centre
        hd = np.unwrap(np.arctan2(*np.gradient(road, axis=0).T[::-1]))
        kappa = np.abs(np.diff(hd)) / np.linalg.norm(np.diff(road, axis=0), axis=1)
        radius = 1.0 / kappa[kappa > 1e-4]
        assert radius.min() > 29.0 and np.percentile(radius, 5) < 46.0 and len(c) > 2


@pytest.mark.parametrize("manoeuvre", ["left", "right", "stop", "lane_change"])
def test_ego_turns_stops_and_changes_lanes(manoeuvre):
    name = "t_junction"
    plan = build_plan(name, 120.0, {})
    layout = plan_layout(plan)
    motion, got = ego_motion(layout, plan, np.random.default_rng(0), 8.0, 12.0, True, True, manoeuvre)
    assert got == manoeuvre
    t = np.arange(0.0, 8.0, 0.05)
    xy, yaw = motion.xy_yaw(t)
    speed = np.linalg.norm(np.diff(xy, axis=0), axis=1) / 0.05
    assert speed.max() <= 15.0 + 1e-6
    turned = np.rad2deg(yaw[-1] - yaw[0])
    if manoeuvre == "left":
        assert turned == pytest.approx(90.0, abs=3.0)
    elif manoeuvre == "right":
        assert turned == pytest.approx(-90.0, abs=3.0)
    elif manoeuvre == "stop":
        assert (speed < 0.05).sum() * 0.05 >= 0.75 and speed.max() > 5.0  # stands, then goes
    else:
        lateral = (xy[-1] - xy[0]) @ np.array([-np.sin(yaw[0]), np.cos(yaw[0])])
        assert lateral == pytest.approx(-3.5, abs=0.05) and abs(turned) < 0.5


def test_vehicles_are_shaped_pedestrians_move_inside_their_cuboids(hard):
    ts0, ts1 = (int(t) for t in hard.timeline.sweeps_ns[[0, 6]])
    bodies = {a.body for a in hard.actors}
    assert {"pedestrian", "cyclist"} <= bodies and bodies & {"car", "suv", "bus", "truck"}
    for ts in (ts0, ts1):
        cuboids, solids = hard.actor_boxes_at(ts), hard.boxes_at(ts)
        for i in range(len(hard.actors)):
            mine = solids.subset(np.flatnonzero(solids.owner == i))
            corners = mine.corners().reshape(-1, 3) - cuboids.center[i]
            local = corners @ cuboids.rotations[i]
            assert np.all(np.abs(local) <= cuboids.size[i] / 2 + 0.01), hard.actors[i].body
    ped = next(i for i, a in enumerate(hard.actors) if a.body == "pedestrian")
    a, b = (hard.boxes_at(t) for t in (ts0, ts1))
    la = a.subset(np.flatnonzero(a.owner == ped))
    lb = b.subset(np.flatnonzero(b.owner == ped))
    rel = [s.rotations.transpose(0, 2, 1) @ hard.actor_boxes_at(t).rotations[ped]
           for s, t in ((la, ts0), (lb, ts1))]
    assert np.abs(rel[0] - rel[1]).max() > 0.05  # limbs swing: not rigid inside the box
    # A car's shape is not its cuboid: a ray grazing the cuboid's top front edge misses the car.
    car = next(i for i, a in enumerate(hard.actors) if a.body in ("car", "suv"))
    box = hard.actor_boxes_at(ts0).subset(np.array([car]))
    R, c, half = box.rotations[0], box.center[0], box.size[0] / 2
    origin = c + R @ np.array([half[0] * 0.97, -5.0, half[2] * 0.95])
    d = R @ np.array([0.0, 1.0, 0.0])
    assert np.isfinite(intersect_rays(origin, d[None], box).t[0])
    mine = hard.boxes_at(ts0).subset(np.flatnonzero(hard.boxes_at(ts0).owner == car))
    assert not np.isfinite(intersect_rays(origin, d[None], mine).t[0])
    assert {13, 14, 10, 12} <= set(hard.furniture.kind.tolist())  # signs, signals, foliage, metal poles
    assert len(np.unique(hard.buildings.params[:, 1].round(2))) > 3  # facades vary


def test_shadows_of_moving_vehicles_move_and_the_sky_is_not_elevation_only(hard):
    sun = hard.sky.sun
    ts0, ts1 = (int(t) for t in hard.timeline.sweeps_ns[[0, 9]])
    vehicles = ("car", "suv", "bus", "truck")
    mover = next(i for i, a in enumerate(hard.actors) if a.body in vehicles and a.speed > 3)
    found = False
    for ts_a, ts_b in ((ts0, ts1), (ts1, ts0)):
        solids = hard.boxes_at(ts_a)
        mine = solids.subset(np.flatnonzero(solids.owner == mover))
        c = hard.actor_boxes_at(ts_a).center[mover]
        ground = c[:2] - sun[:2] / sun[2] * (c[2] - hard.terrain.height(c[None, :2])[0])  # shadow's middle
        p = np.array([*ground, hard.terrain.height(ground[None])[0] + 0.01])

        def shade(s: BoxSet, p=p) -> bool:
            g = shadow_grid(s, sun)
            arrays = (np.ascontiguousarray(s.center), np.ascontiguousarray(s.rotations),
                      np.ascontiguousarray(s.size / 2), np.ascontiguousarray(s.quad))
            return bool(in_shadow(*g.arrays(), *arrays, sun, *p))

        other = hard.boxes_at(ts_b)
        found |= shade(mine) and not shade(other.subset(np.flatnonzero(other.owner == mover)))
    assert found
    out = np.zeros((4, 3))
    sky = hard.sky.packed()
    az = np.arctan2(sun[1], sun[0])
    el = np.arcsin(sun[2])
    for k, a in enumerate((az, az + np.pi, az + 1.0, az + 2.0)):
        sky_color(sky, np.cos(el) * np.cos(a), np.cos(el) * np.sin(a), np.sin(el), out, k)
    assert np.abs(out[0] - out[1]).max() > 20  # the sun's glow
    assert np.ptp(out[1:], axis=0).max() > 3 or np.abs(out[0] - out[2]).max() > 10


def test_camera_effects_vignette_white_balance_noise_and_drift():
    rig = load_rig("av2", scale=0.125)
    cams = [rig.camera("ring_front_left"), rig.camera("ring_side_right")]
    fx = CameraEffects(7, [c.channel for c in cams])
    grey = np.full((cams[0].height, cams[0].width, 3), 120, np.uint8)
    a0 = fx.apply(cams[0], grey, 0.0, 1).astype(float)
    b0 = fx.apply(cams[1], grey, 0.0, 2).astype(float)
    h, w = a0.shape[:2]
    assert a0[:8, :8].mean() < 0.9 * a0[h // 2 - 4: h // 2 + 4, w // 2 - 4: w // 2 + 4].mean()  # vignetting
    ratio = lambda im: im[..., 0].mean() / im[..., 2].mean()  # noqa: E731
    assert abs(ratio(a0) - ratio(b0)) > 0.01  # each camera has its own white balance
    assert np.std(a0[h // 2 - 8: h // 2 + 8, w // 2 - 8: w // 2 + 8, 1]) > 0.5  # sensor noise
    later = [fx.apply(cams[0], grey, t, 10 + k).mean() for k, t in enumerate(np.arange(0.05, 4.0, 0.05))]
    assert np.ptp(later) > 3.0  # exposure drifts over seconds
    again = CameraEffects(7, [c.channel for c in cams]).apply(cams[0], grey, 0.0, 1)
    np.testing.assert_array_equal(again, a0.astype(np.uint8))  # deterministic
    quiet = CameraEffects(7, [c.channel for c in cams], noise=False).apply(cams[0], grey, 0.0, 1)
    quiet = quiet.astype(float)
    centre = (slice(h // 2 - 8, h // 2 + 8), slice(w // 2 - 8, w // 2 + 8), 1)
    assert np.std(quiet[centre]) < 0.5  # camera_noise=False: the same gains without the noise
    assert abs(quiet[centre].mean() - a0[centre].mean()) < 1.0


def test_lidar_noise_dropouts_and_range():
    cfg = dict(seconds=0.3, map_margin_m=20.0, texture_res_m=0.1, lidar_azimuth_steps=256)
    clean = build_world(6, SynthConfig.for_preset("easy", **cfg))
    noisy = build_world(6, SynthConfig.for_preset("easy", lidar_noise=True, **cfg))
    ts = int(clean.timeline.sweeps_ns[1])
    a, b = cast_sweep(clean, ts), cast_sweep(noisy, ts)
    ground_a, ground_b = a.xyz_ego[a.box < 0], b.xyz_ego[b.box < 0]
    assert np.abs(ground_a[:, 2] + EGO_ORIGIN_HEIGHT_M).max() < 1e-6
    # Range noise: each ground return's range minus the exact range to the flat ground along its ray.
    rig = noisy.rig
    origin = np.stack([rig.lidar(n).ego_T_lidar[:3, 3] for n in ("up_lidar", "down_lidar")])[
        (b.laser_number[b.box < 0] >= 32).astype(int)]
    ray = ground_b - origin
    rng_m = np.linalg.norm(ray, axis=1)
    exact = (origin[:, 2] + EGO_ORIGIN_HEIGHT_M) / (-ray[:, 2] / rng_m)
    near = rng_m < 30.0  # float16 storage stays below 1.6 cm there
    assert 0.015 < np.std((rng_m - exact)[near]) < 0.03  # centimetres of range noise
    assert len(b.offset_ns) < 0.97 * len(a.offset_ns)  # dropouts
    far = lambda g: np.sum(np.linalg.norm(g[:, :2], axis=1) > 40.0)  # noqa: E731
    assert far(ground_b) < 0.8 * far(ground_a)  # grazing, dark asphalt far away drops most
    assert np.linalg.norm(b.xyz_ego, axis=1).max() <= noisy.config.lidar_max_range_m + 2.0


def test_label_noise_offsets_jitter_sizes_and_misses(medium):
    noisy = build_world(1, SynthConfig.for_preset("medium", **SMALL))
    assert noisy.config.label_noise
    rows, truth = [], []
    for ts in noisy.timeline.sweeps_ns:
        ts = int(ts)
        rows.append(annotation_rows(noisy, ts, (ret := cast_sweep(noisy, ts)).box, stored_xyz(ret)))
        truth.append(noisy.actor_poses_at(ts))
    n_true = sum(len(t.track_uuid) for t in truth)
    n_rows = sum(len(r["track_uuid"]) for r in rows)
    assert 0 < n_rows < n_true  # some far / occluded objects are not labelled
    size_err, offsets = [], {}
    for r, tr in zip(rows, truth):
        for k, uid in enumerate(r["track_uuid"]):
            i = tr.track_uuid.index(uid)
            lwh = np.array([r["length_m"][k], r["width_m"][k], r["height_m"][k]])
            size_err.append(lwh / tr.size_lwh[i] - 1)
            ego_T_city = np.linalg.inv(noisy.city_T_ego_at(r["timestamp_ns"][k]))
            true_xyz = (ego_T_city @ tr.city_T_box[i])[:3, 3]
            xyz = np.array([r["tx_m"][k], r["ty_m"][k], r["tz_m"][k]])
            offsets.setdefault(uid, []).append(xyz - true_xyz)
    size_err = np.abs(np.array(size_err))
    assert size_err.max() <= 0.1 and size_err.mean() > 0.005
    per_track = [np.mean(v, axis=0) for v in offsets.values() if len(v) >= 5]
    jitter = [np.std(v, axis=0) for v in offsets.values() if len(v) >= 5]
    assert 0.01 < np.mean(np.linalg.norm(per_track, axis=1)) < 0.2  # a per-track offset of centimetres
    assert 0.005 < np.mean(np.array(jitter)[:, :2]) < 0.06  # per-frame jitter of centimetres


def test_label_noise_parts_switch_one_error_each_and_keep_the_others_draws():
    from nuav2.synth.labels import ALL_PARTS, LabelNoiseParts, label_errors

    rng = np.random.default_rng(0)
    k = 40
    yaw = rng.uniform(-np.pi, np.pi, k)
    ego_T_box = np.tile(np.eye(4), (k, 1, 1))
    ego_T_box[:, 0, 0], ego_T_box[:, 0, 1], ego_T_box[:, 1, 0], ego_T_box[:, 1, 1] = (
        np.cos(yaw), -np.sin(yaw), np.sin(yaw), np.cos(yaw))
    ego_T_box[:, :2, 3] = rng.uniform(-80, 80, (k, 2))
    size = rng.uniform(0.5, 5.0, (k, 3))
    points = rng.integers(0, 20, k)
    uids = [f"track-{i}" for i in range(k)]
    args = (7, uids, 123_000_000, ego_T_box, size, points)
    T_all, s_all, kept_all = label_errors(*args)
    T_def, s_def, kept_def = label_errors(*args, ALL_PARTS)
    np.testing.assert_array_equal(T_all, T_def)
    assert not kept_all.all()  # far / few-point objects are missed
    none = LabelNoiseParts(False, False, False, False)
    T0, s0, kept0 = label_errors(*args, none)
    np.testing.assert_allclose(T0, ego_T_box, atol=1e-12)
    np.testing.assert_array_equal(s0, size)
    assert kept0.all()
    T_off, s_off, _ = label_errors(*args, LabelNoiseParts(True, False, False, False))
    T_jit, _, _ = label_errors(*args, LabelNoiseParts(False, False, True, False))
    np.testing.assert_array_equal(s_off, size)
    # offset and jitter add up to the full pose error (box frame), each non-zero on its own
    d_off = np.linalg.inv(ego_T_box) @ T_off
    d_jit = np.linalg.inv(ego_T_box) @ T_jit
    d_all = np.linalg.inv(ego_T_box) @ T_all
    np.testing.assert_allclose(d_off[:, :3, 3] + d_jit[:, :3, 3], d_all[:, :3, 3], atol=1e-9)
    assert np.abs(d_off[:, :3, 3]).mean() > 0.01 and np.abs(d_jit[:, :3, 3]).mean() > 0.005
    _, s_size, kept_miss = label_errors(*args, LabelNoiseParts(False, True, False, True))
    np.testing.assert_array_equal(s_size, s_all)
    np.testing.assert_array_equal(kept_miss, kept_all)
