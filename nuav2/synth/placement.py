"""Where things stand and go in a layout: buildings, parked and moving vehicles, pedestrians,
cyclists and street furniture, placed along a :class:`~nuav2.synth.layouts.StreetPlan`.

Moving vehicles follow lane routes at a cruising speed, slowing for tight turns, and are timed
around the ego's position at mid-log (a lead car ahead on the ego's route, oncoming traffic,
traffic leaving the junction), so a short log still sees them; pedestrians walk along sidewalks,
cyclists ride near the kerb of lanes the ego does not use. Everything draws from the random
stream it is given.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import shapely
from shapely.geometry import Point, Polygon

from nuav2.geometry import F64, make_T
from nuav2.synth import polyline as pl
from nuav2.synth.boxes import KIND_PEDESTRIAN, KIND_VEHICLE, BoxSet
from nuav2.synth.buildings import footprint
from nuav2.synth.config import SynthConfig
from nuav2.synth.layouts import SIDEWALK_W, StreetPlan
from nuav2.synth.legacy import CAR_COLORS, SHIRT_COLORS, ActorTrack, EgoTrajectory, car, uuid4
from nuav2.synth.motion import (
    ACCEL,
    TURN_LAT_ACCEL,
    PathMotion,
    build_route,
    followed_curvature,
    junction_lanes,
    lane_centre,
)
from nuav2.synth.road import RoadLayout
from nuav2.synth.shapes import (
    CYCLIST_SIZE,
    PEDESTRIAN_SIZE,
    VEHICLE_CLASSES,
    SolidList,
    rot_z,
    sign,
    street_light,
    traffic_light,
    tree,
)
from nuav2.synth.terrain import Terrain

PARK_SPACING_M = 6.5
MOVING_TRIES = 4  # draws per moving actor before giving up on one that keeps clear of the others
CLEARANCE_M = 0.4
MOVING_CLASSES = (("car", 0.45), ("suv", 0.25), ("bus", 0.15), ("truck", 0.15))
PARKED_CLASSES = (("car", 0.65), ("suv", 0.35))
SIGN_COLORS = np.array([[200, 30, 35], [235, 235, 235], [240, 200, 40], [30, 80, 170]], np.float32)
LEAF_COLORS = np.array([[70, 110, 45], [55, 95, 50], [95, 120, 50], [60, 85, 40]], np.float32)
FRAME_COLORS = np.array([[40, 40, 45], [180, 30, 30], [30, 90, 170], [210, 210, 210]], np.float32)


def _pick(rng: np.random.Generator, table) -> str:
    names, p = zip(*table)
    return names[int(rng.choice(len(names), p=np.asarray(p) / np.sum(p)))]


def _vehicle_size(rng: np.random.Generator, body: str) -> tuple[str, tuple[float, float, float]]:
    category, *ranges = VEHICLE_CLASSES[body]
    return category, tuple(float(rng.uniform(*r)) for r in ranges)


def _moving(
    uuid: str,
    category: str,
    kind: int,
    size,
    color,
    motion: PathMotion,
    body: str,
    phase=0.0,
    accent=(0.0, 0.0, 0.0),
) -> ActorTrack:
    xy, yaw = motion.xy_yaw(np.array([0.0]))
    return ActorTrack(
        uuid,
        category,
        kind,
        tuple(float(v) for v in size),
        tuple(float(c) for c in color),
        (float(xy[0, 0]), float(xy[0, 1])),
        float(yaw[0]),
        motion.speed,
        body,
        motion,
        float(phase),
        tuple(float(c) for c in accent),
    )


def _constant(path: F64, s_mid: float, speed: float, duration: float, lat: float = 0.0) -> PathMotion:
    t = np.arange(-0.2, duration + 1.0 + 1e-9, 0.05)
    s = s_mid + speed * (t - duration / 2)
    return PathMotion(path, t, s, np.full_like(t, lat))


def _driven(path: F64, s_mid: float, speed: float, duration: float, lat: float = 0.0) -> PathMotion:
    """A vehicle on ``path`` at ``speed``, slowing where the path (as it is followed, smoothed) curves so
    tightly that the lateral acceleration would pass ``TURN_LAT_ACCEL``, braking and speeding up at
    ``ACCEL``; at ``s_mid`` at mid-log. On a straight path it is :func:`_constant`."""
    reach = speed * (duration / 2 + 1.5) + 5.0  # at most this far either side of s_mid in the table
    grid = np.arange(s_mid - reach, s_mid + reach + 0.25, 0.25)
    kappa = followed_curvature(path, grid)
    if not np.any(kappa * speed**2 > TURN_LAT_ACCEL):
        return _constant(path, s_mid, speed, duration, lat)
    v = np.minimum(speed, np.sqrt(TURN_LAT_ACCEL / np.maximum(kappa, 1e-12)))
    ds = np.diff(grid)
    for i in range(1, len(v)):  # speeding up after a turn
        v[i] = min(v[i], np.sqrt(v[i - 1] ** 2 + 2.0 * ACCEL * ds[i - 1]))
    for i in range(len(v) - 2, -1, -1):  # braking before one
        v[i] = min(v[i], np.sqrt(v[i + 1] ** 2 + 2.0 * ACCEL * ds[i]))
    t_at = np.concatenate([[0.0], np.cumsum(2.0 * ds / (v[1:] + v[:-1]))])  # exact for v linear in t
    t_at += duration / 2 - np.interp(s_mid, grid, t_at)
    t = np.arange(-0.2, duration + 1.0 + 1e-9, 0.05)
    return PathMotion(path, t, np.interp(t, t_at, grid), np.full_like(t, lat))


def _footprint_at(a: ActorTrack, t: float) -> Polygon:
    xy, yaw = a.xy_yaw_at(t)
    return footprint(np.asarray(xy), yaw, a.size_lwh[0], a.size_lwh[1])


def ego_footprints(ego: PathMotion | EgoTrajectory, duration: float) -> list[Polygon]:
    """The ego vehicle's footprint (4.9 x 1.9 m around a point 1.4 m ahead of its rear axle) at
    :func:`check_times`."""
    out = []
    for t in check_times(duration):
        if isinstance(ego, PathMotion):
            xy, yaw = ego.xy_yaw(np.array([t]))
            xy, yaw = xy[0], float(yaw[0])
        else:
            x, y, yaw = ego.xy_yaw(np.array([t]))
            xy, yaw = np.array([x[0], y[0]]), float(yaw[0])
        out.append(footprint(xy + 1.4 * np.array([np.cos(yaw), np.sin(yaw)]), yaw, 4.9, 1.9))
    return out


def check_times(duration: float) -> np.ndarray:
    return np.linspace(-0.05, duration + 0.05, max(5, int(duration * 4) + 1))


def clear_of(cand: ActorTrack, others: Sequence[ActorTrack], ego_box: list[Polygon], duration: float) -> bool:
    """True if ``cand`` keeps ``CLEARANCE_M`` from the ego and every other actor over the log."""
    for k, t in enumerate(check_times(duration)):
        f = _footprint_at(cand, t).buffer(CLEARANCE_M)
        if f.intersects(ego_box[k]) or any(f.intersects(_footprint_at(o, t)) for o in others):
            return False
    return True


def dress_legacy_actors(actors: tuple[ActorTrack, ...], rng: np.random.Generator) -> tuple[ActorTrack, ...]:
    """The original actors with shaped bodies: vehicles get a class (and its size), pedestrians walk."""
    out = []
    for a in actors:
        if a.kind == KIND_VEHICLE:
            body = _pick(rng, PARKED_CLASSES if a.speed == 0 else MOVING_CLASSES)
            category, size = _vehicle_size(rng, body)
            out.append(
                ActorTrack(
                    a.track_uuid, category, a.kind, size, a.color, a.start_xy, a.heading, a.speed, body
                )
            )
        else:
            size = tuple(float(rng.uniform(*r)) for r in PEDESTRIAN_SIZE)
            out.append(
                ActorTrack(
                    a.track_uuid,
                    a.category,
                    a.kind,
                    size,
                    a.color,
                    a.start_xy,
                    a.heading,
                    a.speed,
                    "pedestrian",
                    phase=float(rng.uniform(0, 2 * np.pi)),
                )
            )
    return tuple(out)


def _ego_mid(ego: PathMotion, duration: float) -> tuple[F64, F64]:
    xy, yaw = ego.xy_yaw(np.array([duration / 2]))
    return xy[0], np.array([np.cos(yaw[0]), np.sin(yaw[0])])


def _near_lanes(layout: RoadLayout, p: F64, max_d: float):
    out = []
    for ln in layout.lanes:
        if ln.is_intersection:
            continue
        c = lane_centre(ln)
        d = np.linalg.norm(c - p, axis=1)
        k = int(np.argmin(d))
        if d[k] < max_d:
            out.append((ln, pl.tangents(c)[k], float(d[k])))
    return out


def _route_at(layout: RoadLayout, lane_id: int, p: F64) -> tuple[F64, float]:
    route = build_route(layout, lane_id)
    s = pl.arclength(route.path)
    return route.path, float(s[int(np.argmin(np.linalg.norm(route.path - p, axis=1)))])


def place_actors(
    rng: np.random.Generator,
    cfg: SynthConfig,
    plan: StreetPlan,
    layout: RoadLayout,
    ego: PathMotion,
    duration: float,
) -> tuple[ActorTrack, ...]:
    """Parked vehicles, moving vehicles and pedestrians for a general layout."""
    actors: list[ActorTrack] = []
    p_mid, f_mid = _ego_mid(ego, duration)
    ego_pts = ego.xy_yaw(np.linspace(0.0, duration, 9))[0]
    # Parked: slots along parking strips, near the ego's path.
    slots = []
    for road in plan.roads:
        if road.shoulder < 2.2:
            continue
        for side, half in ((-1.0, road.right_half), (1.0, road.left_half)):
            for s in np.arange(6.0, road.length - 3.0, PARK_SPACING_M):
                p = pl.at(road.centre, np.array([s]))[0]
                yaw = float(pl.heading_at(road.centre, np.array([s]))[0])
                n = np.array([-np.sin(yaw), np.cos(yaw)])
                slots.append((p + side * (half - road.shoulder / 2) * n, yaw if side < 0 else yaw + np.pi))
    if slots and cfg.n_parked:
        dist = np.array([np.min(np.linalg.norm(ego_pts - xy, axis=1)) for xy, _ in slots])
        w = np.exp(-dist / 25.0)
        pick = rng.choice(len(slots), size=min(cfg.n_parked, len(slots)), replace=False, p=w / w.sum())
        for i in sorted(pick):
            xy, yaw = slots[i]
            a = car(rng, (float(xy[0]), float(xy[1])), float(yaw + rng.uniform(-0.04, 0.04)), 0.0)
            if cfg.content:
                body = _pick(rng, PARKED_CLASSES)
                category, size = _vehicle_size(rng, body)
                a = ActorTrack(
                    a.track_uuid, category, a.kind, size, a.color, a.start_xy, a.heading, 0.0, body
                )
            actors.append(a)
    n_parked = len(actors)
    # Moving: lead on the ego's route, oncoming, leaving the junction (turning or not).
    juncs = junction_lanes(layout)
    near = _near_lanes(layout, p_mid, 12.0)
    oncoming = [x for x in near if x[1] @ f_mid < -0.5]
    ego_s_mid = float(np.interp(duration / 2, ego.t, ego.s))
    ego_box = ego_footprints(ego, duration)
    for j in range(cfg.n_moving * MOVING_TRIES):
        if len(actors) - n_parked == cfg.n_moving:
            break
        role, rank = ("lead", "oncoming", "leaving")[(j // MOVING_TRIES) % 3], j // (3 * MOVING_TRIES)
        color = CAR_COLORS[rng.integers(len(CAR_COLORS))]
        body = _pick(rng, MOVING_CLASSES) if cfg.content else "box"
        category, size = (
            _vehicle_size(rng, body)
            if cfg.content
            else ("REGULAR_VEHICLE", (rng.uniform(4.2, 5.0), rng.uniform(1.8, 2.0), rng.uniform(1.45, 1.8)))
        )
        if role == "lead":
            lat = float(ego.lat[-1])
            v = float(np.max(np.gradient(ego.s, ego.t))) * rng.uniform(1.0, 1.08)
            motion = _driven(
                ego.path, ego_s_mid + 24.0 + 15.0 * rank + rng.uniform(0, 8) + size[0] / 2, v, duration, lat
            )
        elif role == "oncoming" and oncoming:
            ln = oncoming[(rank + int(rng.integers(len(oncoming)))) % len(oncoming)][0]
            path, s_near = _route_at(layout, ln.id, p_mid)
            motion = _driven(path, s_near + rng.uniform(-40.0, 10.0), rng.uniform(7.0, 11.0), duration)
        elif juncs:
            via = juncs[int(rng.integers(len(juncs)))]
            route = build_route(layout, via.id)
            s0, s1 = route.marks[via.id]
            motion = _driven(route.path, s1 + rng.uniform(8.0, 30.0), rng.uniform(5.0, 9.0), duration)
        else:  # one road: a same-direction neighbour lane, well ahead of or behind the ego
            beside = [x for x in near if x[1] @ f_mid > 0.5 and x[2] > 2.5] or oncoming or near
            ln = beside[(rank + int(rng.integers(len(beside)))) % len(beside)][0]
            path, s_near = _route_at(layout, ln.id, p_mid)
            v = float(np.max(np.gradient(ego.s, ego.t))) * rng.uniform(1.0, 1.15)  # stays ahead of the ego
            motion = _driven(path, s_near + rng.uniform(20.0, 45.0), v, duration)
        cand = _moving(uuid4(rng), category, KIND_VEHICLE, size, color, motion, body)
        if clear_of(cand, actors, ego_box, duration):
            actors.append(cand)
    # Pedestrians: along the sidewalks nearest the ego.
    lines = []
    for road in plan.roads:
        for side, half in ((1.0, road.left_half), (-1.0, road.right_half)):
            line = pl.offset(road.centre, side * (half + SIDEWALK_W / 2))
            lines.append((float(np.min(np.linalg.norm(line - p_mid, axis=1))), line))
    lines.sort(key=lambda x: x[0])
    for j in range(cfg.n_pedestrians):
        line = lines[j % min(len(lines), 2)][1]
        if rng.uniform() < 0.5:
            line = line[::-1]
        s_near = float(pl.arclength(line)[int(np.argmin(np.linalg.norm(line - p_mid, axis=1)))])
        motion = _constant(
            line, s_near + rng.uniform(-15.0, 25.0), rng.uniform(1.1, 1.5), duration, rng.uniform(-0.6, 0.6)
        )
        shirt = SHIRT_COLORS[rng.integers(len(SHIRT_COLORS))]
        if cfg.content:
            size = tuple(rng.uniform(*r) for r in PEDESTRIAN_SIZE)
            actors.append(
                _moving(
                    uuid4(rng),
                    "PEDESTRIAN",
                    KIND_PEDESTRIAN,
                    size,
                    shirt,
                    motion,
                    "pedestrian",
                    rng.uniform(0, 2 * np.pi),
                )
            )
        else:
            size = (rng.uniform(0.5, 0.7), rng.uniform(0.5, 0.7), rng.uniform(1.6, 1.9))
            actors.append(_moving(uuid4(rng), "PEDESTRIAN", KIND_PEDESTRIAN, size, shirt, motion, "box"))
    return tuple(actors)


def place_cyclists(
    rng: np.random.Generator,
    cfg: SynthConfig,
    layout: RoadLayout,
    ego: PathMotion | EgoTrajectory,
    duration: float,
    actors: tuple[ActorTrack, ...],
) -> tuple[ActorTrack, ...]:
    """Cyclists near the kerb of outer lanes around the ego, clear of it and of the other actors."""
    ego_box = ego_footprints(ego, duration)
    mid = ego_box[len(ego_box) // 2].centroid
    ego_mid = np.array([mid.x, mid.y])
    outer = [x for x in _near_lanes(layout, ego_mid, 25.0) if x[0].right_neighbor_id is None]
    if not outer:
        return ()
    out: list[ActorTrack] = []
    for _ in range(cfg.n_cyclists * MOVING_TRIES):
        if len(out) == cfg.n_cyclists:
            break
        ln = outer[int(rng.integers(len(outer)))][0]
        path, s_near = _route_at(layout, ln.id, ego_mid)
        motion = _driven(path, s_near + rng.uniform(-30.0, 30.0), rng.uniform(4.0, 6.5), duration, -1.0)
        shirt = SHIRT_COLORS[rng.integers(len(SHIRT_COLORS))]
        frame = FRAME_COLORS[rng.integers(len(FRAME_COLORS))]
        cand = _moving(uuid4(rng), "BICYCLIST", KIND_PEDESTRIAN, CYCLIST_SIZE, shirt, motion, "cyclist",
                       accent=frame)
        if clear_of(cand, [*actors, *out], ego_box, duration):
            out.append(cand)
    return tuple(out)


def place_furniture(
    rng: np.random.Generator, plan: StreetPlan, layout: RoadLayout, terrain: Terrain
) -> BoxSet:
    """Street lights, signs and trees along the sidewalks, median trees, and traffic lights at junctions."""
    road_area = layout.drivable_union().buffer(0.3)
    crossings = (
        shapely.union_all([Polygon(cw.polygon) for cw in layout.crosswalks]).buffer(1.5)
        if layout.crosswalks
        else Polygon()
    )
    parts: list[BoxSet] = []
    taken: list[F64] = []

    def put(solids: SolidList, xy: F64, yaw: float, clearance: float) -> None:
        if road_area.contains(Point(xy)) or crossings.contains(Point(xy)):
            return
        if any(np.linalg.norm(xy - t) < clearance for t in taken):
            return
        taken.append(xy)
        z = float(terrain.height(xy[None])[0])
        parts.append(solids.boxset(make_T(rot_z(yaw), [xy[0], xy[1], z]), -1))

    for road in plan.roads:
        L = road.length
        for side, half in ((1.0, road.left_half), (-1.0, road.right_half)):

            def frame(s: float, lateral: float, road=road, side=side) -> tuple[F64, float, F64]:
                p = pl.at(road.centre, np.array([s]))[0]
                yaw = float(pl.heading_at(road.centre, np.array([s]))[0])
                n = np.array([-np.sin(yaw), np.cos(yaw)])
                return p + side * lateral * n, yaw, n

            for s in np.arange(rng.uniform(4.0, 20.0), L - 2.0, rng.uniform(28.0, 36.0)):
                xy, yaw, n = frame(s, half + 0.7)
                toward_road = -side * n
                put(
                    street_light(rng.uniform(7.0, 9.0)),
                    xy,
                    float(np.arctan2(toward_road[1], toward_road[0])),
                    2.0,
                )
            for s in np.arange(rng.uniform(8.0, 40.0), L - 2.0, rng.uniform(35.0, 60.0)):
                xy, yaw, _ = frame(s, half + 0.5)
                facing = yaw + np.pi if side < 0 else yaw  # toward the traffic approaching on this side
                k = int(rng.integers(len(SIGN_COLORS)))
                shape = ("round", "square", "diamond", "square")[k] if rng.uniform() < 0.7 else "round"
                put(sign(rng.uniform(2.1, 2.5), SIGN_COLORS[k], shape), xy, float(facing), 1.5)
            for s in np.arange(rng.uniform(3.0, 10.0), L - 2.0, rng.uniform(8.0, 13.0)):
                if rng.uniform() < 0.3:
                    continue
                xy, _, _ = frame(s, half + SIDEWALK_W - 0.9)
                r = rng.uniform(1.3, 2.1)
                put(
                    tree(
                        rng.uniform(2.0, 3.0),
                        rng.uniform(0.12, 0.2),
                        (r, r * rng.uniform(0.85, 1.0), r * rng.uniform(1.0, 1.4)),
                        LEAF_COLORS[rng.integers(len(LEAF_COLORS))],
                    ),
                    xy,
                    float(rng.uniform(0, np.pi)),
                    3.0,
                )
        if road.median >= 2.0:
            for s in np.arange(rng.uniform(3.0, 9.0), L - 2.0, rng.uniform(10.0, 14.0)):
                p = pl.at(road.centre, np.array([s]))[0]
                r = min(rng.uniform(1.3, 1.9), road.median / 2 + 0.3)
                put(
                    tree(
                        rng.uniform(2.2, 3.0),
                        0.15,
                        (r, r, r * 1.3),
                        LEAF_COLORS[rng.integers(len(LEAF_COLORS))],
                    ),
                    p,
                    0.0,
                    3.0,
                )
    for junc in plan.junctions:
        c = np.asarray(junc.centre, np.float64)
        for road_i, at_start in junc.arms:
            road = plan.roads[road_i]
            u = pl.tangents(road.centre)[0] if at_start else -pl.tangents(road.centre)[-1]
            n = np.array([-u[1], u[0]])
            hi = road.left_half if at_start else road.right_half
            n_in = road.n_bwd if at_start else road.n_fwd
            xy = c + (junc.edge + 1.2) * u + (hi + 0.7) * n
            reach = hi + 0.7 - (road.median / 2 + 0.5 * n_in * 3.5)
            put(traffic_light(float(reach), int(rng.integers(3))), xy, float(np.arctan2(u[1], u[0])), 0.5)
    return BoxSet.concat(*parts) if parts else BoxSet.empty()
