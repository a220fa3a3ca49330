"""Motion along coarse polylines is smooth: positions, heading and yaw rate are continuous, junction
turns yaw at rates a car can (tens of deg/s, not a 0 / 150 deg/s staircase), and the lane change's
lateral motion starts and ends without a yaw-rate step. Fails on a heading taken from the polyline's
piecewise-constant direction."""

from __future__ import annotations

import numpy as np
import pytest

from nuav2.synth import SynthConfig, build_world
from nuav2.synth import polyline as pl
from nuav2.synth.boxes import KIND_VEHICLE
from nuav2.synth.layouts import build_plan, draw_params, plan_layout
from nuav2.synth.motion import (
    PATH_SMOOTH_M,
    TURN_LAT_ACCEL,
    PathMotion,
    ego_motion,
    lane_change_offset,
)

DT_S = 0.01  # 100 Hz samples
MAX_TURN_DEG_S = 45.0  # a car on a junction turn
MAX_RATE_STEP_DEG_S = 2.0  # yaw-rate change between consecutive 100 Hz samples (200 deg/s^2)


def _coarse_turn(radius: float = 12.0, spacing: float = 1.0) -> np.ndarray:
    """A 90 deg left turn as a junction lane's centre line is: 36 m straight in (long segments), an arc
    with vertices ``spacing`` apart from (0, 0), 36 m straight out."""
    n = int(np.ceil(radius * np.pi / 2 / spacing))
    th = np.linspace(0.0, np.pi / 2, n + 1)
    arc = np.column_stack([radius * np.sin(th), radius - radius * np.cos(th)])
    lead = np.array([[-36.0, 0.0], [-20.0, 0.0]])
    out = arc[-1] + np.array([[0.0, 20.0], [0.0, 36.0]])
    return np.vstack([lead, arc, out])


def _yaw_rate_deg_s(yaw: np.ndarray) -> np.ndarray:
    return np.rad2deg(np.diff(np.unwrap(yaw)) / DT_S)


def _check_smooth_motion(xy: np.ndarray, yaw: np.ndarray, max_speed: float, max_rate: float,
                         max_rate_step: float = MAX_RATE_STEP_DEG_S) -> None:
    """Yaw rate bounded and continuous; positions without steps; yaw along the velocity."""
    rate = _yaw_rate_deg_s(yaw)
    assert np.abs(rate).max() < max_rate, np.abs(rate).max()
    assert np.abs(np.diff(rate)).max() < max_rate_step, np.abs(np.diff(rate)).max()
    step = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    assert step.max() <= max_speed * DT_S + 1e-6, (step.max(), max_speed * DT_S)
    moving = step > 0.05 * DT_S
    if not moving.any():
        return
    v_dir = np.arctan2(*np.diff(xy, axis=0)[moving].T[::-1])
    mid_yaw = 0.5 * (yaw[1:] + yaw[:-1])[moving]
    assert np.rad2deg(np.abs(np.angle(np.exp(1j * (v_dir - mid_yaw))))).max() < 0.5  # no crabbing
    # the velocity's direction turns no faster than the yaw does (no kinks at the path's vertices)
    turn = np.rad2deg(np.abs(np.angle(np.exp(1j * np.diff(v_dir))))) / DT_S
    assert turn.max() < max_rate + max_rate_step, turn.max()


def test_smoothed_polyline_is_exact_on_straights_and_twice_differentiable():
    xy = _coarse_turn()
    c = pl.arclength(xy)
    s = np.linspace(0.0, c[-1], 6001)
    p, d1, d2 = pl.smooth(xy, s, PATH_SMOOTH_M)
    ds = s[1] - s[0]
    np.testing.assert_allclose(np.gradient(p, ds, axis=0)[1:-1], d1[1:-1], atol=1e-4)
    np.testing.assert_allclose(np.gradient(d1, ds, axis=0)[2:-2], d2[2:-2], atol=2e-3)
    straight = (s < 36.0 - PATH_SMOOTH_M) | (s > c[-1] - 36.0 + PATH_SMOOTH_M)
    np.testing.assert_allclose(p[straight], pl.at(xy, s[straight]), atol=1e-9)
    np.testing.assert_allclose(p[[0, -1]], xy[[0, -1]], atol=1e-9)
    kappa = (d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]) / np.linalg.norm(d1, axis=1) ** 3
    on_arc = (s > 36.0 + 2 * PATH_SMOOTH_M) & (s < c[-1] - 36.0 - 2 * PATH_SMOOTH_M)
    assert kappa[on_arc] == pytest.approx(1 / 12.0, rel=0.05)  # no vertex staircase in the curvature
    assert np.abs(np.diff(kappa)).max() < 0.002  # continuous
    radius = np.linalg.norm(p[on_arc] - [0.0, 12.0], axis=1)
    assert np.abs(radius - 12.0).max() < 0.06  # the corner is cut by centimetres


@pytest.mark.parametrize("lateral", ["centre", "offset", "lane_change"])
def test_coarse_polyline_turn_has_a_continuous_yaw_rate(lateral):
    xy_path = _coarse_turn()
    t = np.arange(-0.2, 9.0 + 1e-9, DT_S)
    v = 5.0
    s = 18.0 + v * t
    lat = {"centre": np.zeros_like(t), "offset": np.full_like(t, -1.0),
           "lane_change": lane_change_offset(t, 8.0, -3.5)}[lateral]
    motion = PathMotion(xy_path, t, s, lat)
    ts = np.arange(0.0, 8.0, DT_S)
    xy, yaw = motion.xy_yaw(ts)
    # outside the turn the offset path is as fast as the centre; 1 m outside a 12 m radius, 1/12 faster
    _check_smooth_motion(xy, yaw, v * (1.0 + 1.0 / 12.0) + (1.5 if lateral == "lane_change" else 0.0),
                         MAX_TURN_DEG_S)
    rate = _yaw_rate_deg_s(yaw)
    mid = np.abs(ts[1:] - 5.5) < 1.0  # in the middle of the arc (s 36 to 54.8)
    expect = np.rad2deg(v / 12.0)
    if lateral == "centre":
        assert rate[mid] == pytest.approx(expect, rel=0.06)
    assert np.rad2deg(np.unwrap(yaw)[-1] - yaw[0]) == pytest.approx(90.0, abs=0.5)


def test_a_motion_on_a_coarse_table_is_as_smooth_as_on_a_fine_one():
    """Actors' tables are 20 Hz; the motion refines them, so their yaw rate has no 20 Hz steps."""
    xy_path = _coarse_turn()
    t = np.arange(-0.2, 9.0 + 1e-9, 0.05)
    motion = PathMotion(xy_path, t, 18.0 + 8.0 * t, np.zeros_like(t))
    xy, yaw = motion.xy_yaw(np.arange(0.0, 8.0, DT_S))
    _check_smooth_motion(xy, yaw, 8.0, 45.0, max_rate_step=3.0)


def _kappa_max(motion: PathMotion, t: np.ndarray) -> float:
    s = np.interp(t, motion.t, motion.s)
    _, d1, d2 = pl.smooth(motion.path, s, PATH_SMOOTH_M)
    return float(np.max(np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]) / np.linalg.norm(d1, axis=1) ** 3))


@pytest.mark.parametrize("name,params_seed", [("four_way", 0), ("t_junction", 0), ("y_junction", 0),
                                              ("y_junction", 1), ("y_junction", 2)])
@pytest.mark.parametrize("manoeuvre", ["left", "right", "lane_change"])
def test_ego_junction_turns_and_lane_changes_yaw_like_a_car(name, params_seed, manoeuvre):
    plan = build_plan(name, 120.0, draw_params(name, np.random.default_rng(params_seed)))
    layout = plan_layout(plan)
    duration = 8.0
    for draw in range(2):
        rng = np.random.default_rng(draw)
        motion, got = ego_motion(layout, plan, rng, duration, 12.0, True, True, manoeuvre)
        assert got == manoeuvre
        t = np.arange(0.0, duration, DT_S)
        xy, yaw = motion.xy_yaw(t)
        speed = np.gradient(np.interp(t, motion.t, motion.s), t)
        rate = np.deg2rad(np.abs(_yaw_rate_deg_s(yaw)))
        if manoeuvre == "lane_change":
            _check_smooth_motion(xy, yaw, 12.0 * 1.02, 6.0, max_rate_step=0.3)  # no step as it starts
            continue
        _check_smooth_motion(xy, yaw, speed.max() + 0.05, 90.0)
        assert (rate * speed[1:]).max() < 1.1 * TURN_LAT_ACCEL  # lateral acceleration of a turn
        if _kappa_max(motion, t) < 1 / 4.5:  # a radius a car can drive (not y_junction's sharpest)
            assert np.rad2deg(rate).max() < MAX_TURN_DEG_S
        assert abs(np.rad2deg(np.unwrap(yaw)[-1] - yaw[0])) > 20.0  # it did turn


@pytest.fixture(scope="module")
def turning_world():
    world = build_world(1, SynthConfig.for_preset("medium", seconds=2.0, map_margin_m=20.0))
    assert world.manoeuvre == "left"
    return world


def test_world_ego_and_actors_yaw_smoothly(turning_world):
    w = turning_world
    t = np.arange(0.0, 2.0, DT_S)
    ts_ns = w.timeline.t0_ns + np.round(t * 1e9).astype(np.int64)
    T = w.local_T_ego_at(ts_ns)
    yaw = np.arctan2(T[:, 1, 0], T[:, 0, 0])
    rate = np.abs(_yaw_rate_deg_s(yaw))
    assert 10.0 < rate.max() < MAX_TURN_DEG_S  # it turns, as a car does
    _check_smooth_motion(T[:, :2, 3], yaw, float(np.max(np.diff(w.ego.s) / np.diff(w.ego.t))) + 0.05,
                         MAX_TURN_DEG_S)
    moving = [a for a in w.actors if a.motion is not None and a.motion.speed > 0]
    assert moving
    turned = 0.0
    for a in moving:
        poses = [a.xy_yaw_at(float(x)) for x in t]
        xy = np.array([p[0] for p in poses]).reshape(-1, 2)
        a_yaw = np.array([p[1] for p in poses], np.float64).reshape(-1)
        top_speed = float(np.max(np.diff(a.motion.s) / np.diff(a.motion.t)))  # cruising, before a turn
        _check_smooth_motion(xy, a_yaw, top_speed + 0.05, MAX_TURN_DEG_S, max_rate_step=3.0)
        turned = max(turned, np.abs(_yaw_rate_deg_s(a_yaw)).max())
    assert turned > 10.0  # an actor on a junction turn is among them


@pytest.mark.parametrize("seed", [1, 3, 13])
def test_vehicles_slow_for_tight_turns(seed):
    """Moving vehicles (and cyclists) take junction turns with at most TURN_LAT_ACCEL of lateral
    acceleration, as drivers do (at their cruising speed a bus on an 8 m right turn pulled 11 m/s^2)."""
    w = build_world(seed, SynthConfig.for_preset("medium", seconds=6.0))
    t = np.arange(0.0, 6.0, DT_S)
    worst = 0.0
    for a in w.actors:
        if a.motion is None or a.kind != KIND_VEHICLE or a.motion.speed == 0:
            continue
        xy, yaw = a.motion.xy_yaw(t)
        speed = np.linalg.norm(np.diff(xy, axis=0), axis=1) / DT_S
        lateral = np.abs(np.diff(np.unwrap(yaw))) / DT_S * speed
        worst = max(worst, float(lateral.max()))
    assert 0.5 < worst <= 1.05 * TURN_LAT_ACCEL  # someone turns, nobody faster than a driver would
