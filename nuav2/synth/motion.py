"""Motion along the lane graph: routes, speed profiles (stop and go, slowing for turns), lane changes.

A :class:`PathMotion` is a path (a lane route's centre line), an arc length s(t) from a speed
profile and a lateral offset l(t) (a lane change is a quintic smoothstep of one lane width, so its
lateral acceleration, and with it the yaw rate, has no step), tabulated at 100 Hz and interpolated.
The path is followed as :func:`polyline.smooth` rounds it (``PATH_SMOOTH_M``): a lane's centre line is
a polyline with vertices about 1 m apart on junction curves, whose direction jumps at every vertex; the
smoothed path has a continuous heading and curvature, so the yaw rate is continuous too (on a junction
turn at 5 m/s, 20-30 deg/s, not alternating between 0 and 150 deg/s). The lateral offset is taken along
the smoothed path's normal; the heading follows the velocity of the offset path (no crabbing, a lane
change's lateral motion included), and holds while stopped. Manoeuvres are centred on the middle of
the log, so even a 2 s log sees its turn, stop or change.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from nuav2.geometry import F64
from nuav2.synth import polyline as pl
from nuav2.synth.layouts import StreetPlan
from nuav2.synth.road import LANE_W, LaneSpec, RoadLayout

TABLE_HZ = 100.0
ACCEL = 2.0  # m/s^2, speeding up and braking
STOP_FRONT_M = 5.0  # the ego origin (rear axle) stops this far before a stop bar's lane end
PATH_SMOOTH_M = 2.0  # half-width (m of arc length) of the triangle kernel that rounds a path's vertices
TURN_MPS = 5.0  # speed through a junction turn, unless its curvature asks for less:
TURN_LAT_ACCEL = 2.5  # m/s^2, the most lateral acceleration a turn gets (a tight right turn is slower)
MOVING_MPS = 0.05  # slower than this the heading holds (the path's) instead of following the velocity


def lane_centre(lane: LaneSpec) -> F64:
    n = max(len(lane.left), len(lane.right), 2)
    return 0.5 * (pl.resample(lane.left, n) + pl.resample(lane.right, n))


def _heading_change(lane: LaneSpec) -> float:
    c = lane_centre(lane)
    t0, t1 = pl.tangents(c)[[0, -1]]
    return float(np.arctan2(t0[0] * t1[1] - t0[1] * t1[0], t0 @ t1))


def turn_kind(lane: LaneSpec) -> str:
    """'left', 'right' or 'straight' for a junction lane."""
    a = _heading_change(lane)
    return "left" if a > np.deg2rad(35) else ("right" if a < -np.deg2rad(35) else "straight")


@dataclass(frozen=True, eq=False)
class Route:
    lanes: tuple[int, ...]
    path: F64  # (N, 2) centre line
    marks: dict[int, tuple[float, float]]  # lane id -> (s start, s end) along the path


def build_route(layout: RoadLayout, via: int) -> Route:
    """The route through lane ``via``: back along predecessors to the map edge, on along successors."""
    by_id = {ln.id: ln for ln in layout.lanes}
    back, cur = [], by_id[via]
    seen = {via}
    while cur.predecessors:
        preds = [p for p in cur.predecessors if p not in seen and not by_id[p].is_intersection] or [
            p for p in cur.predecessors if p not in seen
        ]
        if not preds:
            break
        cur = by_id[preds[0]]
        seen.add(cur.id)
        back.append(cur.id)
    fwd, cur = [], by_id[via]
    while cur.successors:
        nxt = [s for s in cur.successors if s not in seen and not by_id[s].is_intersection] or [
            s for s in cur.successors if s not in seen and turn_kind(by_id[s]) == "straight"
        ]
        if not nxt:
            break
        cur = by_id[nxt[0]]
        seen.add(cur.id)
        fwd.append(cur.id)
    ids = tuple(back[::-1] + [via] + fwd)
    parts = [lane_centre(by_id[i]) for i in ids]
    marks, s = {}, 0.0
    for i, p in zip(ids, parts):
        length = float(pl.arclength(p)[-1])
        marks[i] = (s, s + length)
        s += length
    return Route(ids, pl.concat(parts), marks)


def followed_curvature(path: F64, s: F64) -> F64:
    """|curvature| (1/m) at arc lengths ``s`` of ``path`` as vehicles follow it (smoothed)."""
    _, d1, d2 = pl.smooth(path, s, PATH_SMOOTH_M)
    return np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]) / np.linalg.norm(d1, axis=1) ** 3


def turn_speed(path: F64, s0: float, s1: float, v_max: float = TURN_MPS) -> float:
    """Speed through the piece [s0, s1] of ``path`` (as it is followed, smoothed): ``v_max``, or less where
    its tightest curvature would take the lateral acceleration above ``TURN_LAT_ACCEL``."""
    kappa = followed_curvature(path, np.linspace(s0, s1, 200))
    return float(min(v_max, np.sqrt(TURN_LAT_ACCEL / max(float(kappa.max()), 1e-9))))


def junction_lanes(layout: RoadLayout) -> list[LaneSpec]:
    return [ln for ln in layout.lanes if ln.is_intersection]


def speed_table(
    kind: str, duration: float, v_cruise: float, *, hold_s: float = 0.0, v_slow: float = 0.0
) -> tuple[F64, F64]:
    """(t, S): time since the log start (100 Hz, -0.2 s to duration + 1 s) and arc length relative to the
    event at mid-log. ``kind``: 'cruise', 'stop' (standstill for ``hold_s``) or 'slow' (``v_slow``
    for ``hold_s``)."""
    t = np.arange(-0.2, duration + 1.0 + 1e-9, 1.0 / TABLE_HZ)  # cameras fire up to 22.5 ms before sweep 0
    tau = t - duration / 2
    if kind == "cruise":
        v = np.full_like(t, v_cruise)
    else:
        base = 0.0 if kind == "stop" else v_slow
        v = np.minimum(v_cruise, base + ACCEL * np.maximum(np.abs(tau) - hold_s / 2, 0.0))
    # S(tau) = integral of v from the event (tau = 0), exact for piecewise-linear v (trapezoids).
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t))])
    return t, cum - np.interp(0.0, tau, cum)


@dataclass(frozen=True, eq=False)
class PathMotion:
    """Position and heading along ``path`` from tabulated arc length and lateral offset."""

    path: F64
    t: F64  # (K,) seconds since the log start
    s: F64  # (K,) arc length on the path
    lat: F64  # (K,) offset to the left of the path (m)

    @property
    def speed(self) -> float:
        """Mean speed over the table (0: parked / standing)."""
        return float((self.s[-1] - self.s[0]) / max(self.t[-1] - self.t[0], 1e-9))

    @cached_property
    def _table(self) -> tuple[F64, F64, F64]:
        """(t, xy, yaw) at TABLE_HZ or finer: the given table, refined where it is coarser."""
        t, s, lat = self.t, self.s, self.lat
        if len(t) > 1 and float(np.max(np.diff(t))) > 1.0 / TABLE_HZ + 1e-9:
            fine = np.linspace(t[0], t[-1], int(np.ceil((t[-1] - t[0]) * TABLE_HZ - 1e-6)) + 1)
            s, lat, t = np.interp(fine, t, s), np.interp(fine, t, lat), fine
        s = np.clip(s, 0.0, pl.arclength(self.path)[-1])  # the path's ends hold
        p, d1, d2 = pl.smooth(self.path, s, PATH_SMOOTH_M)
        speed_s = np.linalg.norm(d1, axis=1)  # |dp/ds|, 1 on straights, a little less in curves
        e = d1 / speed_s[:, None]
        n = np.column_stack([-e[:, 1], e[:, 0]])
        head = np.unwrap(np.arctan2(e[:, 1], e[:, 0]))
        dhead_ds = (d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]) / speed_s**2
        xy = p + lat[:, None] * n
        if len(t) < 2:
            return t, xy, head
        # Velocity of p(s) + lat n(s): s' (|p'| - lat head') e + lat' n, exact for the smoothed path.
        s_dot, lat_dot = np.gradient(s, t), np.gradient(lat, t)
        v_e, v_n = s_dot * (speed_s - lat * dhead_ds), lat_dot
        moving = np.hypot(v_e, v_n) > MOVING_MPS
        return t, xy, head + np.where(moving, np.arctan2(v_n, v_e), 0.0)

    def xy_yaw(self, t_s: F64) -> tuple[F64, F64]:
        t, p, yaw = self._table
        t_s = np.atleast_1d(np.asarray(t_s, np.float64))
        xy = np.column_stack([np.interp(t_s, t, p[:, 0]), np.interp(t_s, t, p[:, 1])])
        return xy, np.interp(t_s, t, yaw)


def lane_change_offset(t: F64, duration: float, width: float, change_s: float = 5.0) -> F64:
    """Lateral offset of a lane change centred on mid-log: a quintic smoothstep (zero lateral speed and
    acceleration at both ends, so the yaw rate starts and ends without a step); over 5 s its peak
    lateral speed (1.3 m/s for a 3.5 m lane) is what a 4 s cubic smoothstep had."""
    u = np.clip((t - (duration / 2 - change_s / 2)) / change_s, 0.0, 1.0)
    return width * u**3 * (10.0 - 15.0 * u + 6.0 * u * u)


def ego_motion(
    layout: RoadLayout,
    plan: StreetPlan,
    rng: np.random.Generator,
    duration: float,
    v_cruise: float,
    varied: bool,
    lane_change: bool,
    manoeuvre: str | None = None,
) -> tuple[PathMotion, str]:
    """The ego's motion and the name of its manoeuvre.

    ``varied`` (the layouts factor): turn left or right, stop and go at a stop bar, or change lanes,
    as the layout allows (``manoeuvre`` forces one); otherwise cruise straight on, drifting one lane
    right mid-log when ``lane_change`` (the original ego's behaviour)."""
    juncs = junction_lanes(layout)
    straight_inner = [ln for ln in juncs if turn_kind(ln) == "straight" and ln.right_neighbor_id is not None]
    options = ["lane_change"]
    if juncs:
        options += ["left", "right", "stop"]
    elif plan.midblock_crossings:
        options += ["stop"]
    else:
        options += ["slow"]
    drawn = options[int(rng.integers(len(options)))] if varied else "cruise"
    manoeuvre = manoeuvre or drawn
    if juncs and manoeuvre in ("left", "right"):
        cands = [ln for ln in juncs if turn_kind(ln) == manoeuvre]
        if not cands:
            manoeuvre = "stop"
    if juncs:
        if manoeuvre in ("left", "right"):
            via = cands[int(rng.integers(len(cands)))]
        else:
            pool = straight_inner or [ln for ln in juncs if turn_kind(ln) == "straight"]
            via = pool[int(rng.integers(len(pool)))]
        route = build_route(layout, via.id)
        s_via0, s_via1 = route.marks[via.id]
    else:
        # One road: an inner (left-most) lane of one direction, from end to end.
        firsts = [ln for ln in layout.lanes if not ln.predecessors and ln.right_neighbor_id is not None]
        via = firsts[int(rng.integers(len(firsts)))]
        route = build_route(layout, via.id)
        mid = 0.5 * float(pl.arclength(route.path)[-1])
        s_via0 = s_via1 = mid
    lat = 0.0
    if manoeuvre in ("left", "right"):
        v_turn = turn_speed(route.path, s_via0, s_via1)
        hold = (s_via1 - s_via0) / v_turn
        t, S = speed_table("slow", duration, v_cruise, hold_s=hold, v_slow=v_turn)
        s = 0.5 * (s_via0 + s_via1) + S
    elif manoeuvre == "stop":
        if juncs:
            s_stop = s_via0 - STOP_FRONT_M
        else:  # the midblock crossing: the ego's lane passes it at the road's middle
            road_i, s_cross = plan.midblock_crossings[0]
            centre = plan.roads[road_i].centre
            p_cross = pl.at(centre, np.array([s_cross]))[0]
            s_on = pl.arclength(route.path)
            s_stop = float(s_on[np.argmin(np.linalg.norm(route.path - p_cross, axis=1))]) - 3.4 - STOP_FRONT_M
        t, S = speed_table("stop", duration, v_cruise, hold_s=float(rng.uniform(0.8, 1.6)))
        s = s_stop + S
    elif manoeuvre == "slow":
        t, S = speed_table("slow", duration, v_cruise, hold_s=1.0, v_slow=0.5 * v_cruise)
        s = s_via0 + S
    else:
        t, S = speed_table("cruise", duration, v_cruise)
        s = (s_via0 - 30.0 - 0.5 * v_cruise * 4.0 if juncs else s_via0) + S
        if manoeuvre == "lane_change" or (manoeuvre == "cruise" and lane_change):
            lat = -LANE_W  # one lane to the right
    lat_t = lane_change_offset(t, duration, lat) if lat else np.zeros_like(t)
    return PathMotion(route.path, t, s, lat_t), manoeuvre
