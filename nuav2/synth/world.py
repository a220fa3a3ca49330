"""SyntheticWorld: the procedural, seed-deterministic scene behind a synthetic AV2 log.

It holds the road layout, building lots, actor tracks, the ego trajectory and the sensor
timeline, all analytic in continuous time, so any sensor (the log's own, or another rig at
any pose) can be rendered from it. Geometry lives in a *local* frame (origin at the
intersection centre on the ground, x east, y north); ``city_T_local`` is a pure translation
by km-scale offsets and a non-zero ground height, so downstream float32 recentring is
exercised. The ego origin rides ``EGO_ORIGIN_HEIGHT_M`` above the flat ground, as in AV2.
"""

from __future__ import annotations

import json
import uuid
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
from shapely.geometry import Polygon

from nuav2.geometry import F64, make_T, translation_T
from nuav2.rig import Rig, load_rig
from nuav2.synth.boxes import KIND_BUILDING, KIND_PEDESTRIAN, KIND_VEHICLE, BoxSet
from nuav2.synth.config import SynthConfig
from nuav2.synth.road import (
    DRIVABLE_HALF,
    INTER_HALF,
    LANE_W,
    SIDEWALK_W,
    RoadLayout,
    arm_length_for,
    build_road_layout,
    rot90,
)
from nuav2.synth.texture import GroundTexture, build_ground_texture
from nuav2.synth.timeline import Timeline, make_timeline

WORLD_FILE = "synthetic_world.json"
WORLD_FORMAT = "nuav2-synthetic/1"
GENERATOR_VERSION = 1  # bump when the same seed and config would give a different world
EGO_ORIGIN_HEIGHT_M = 0.32
RING_CAMERAS = ("ring_front_center", "ring_front_left", "ring_front_right", "ring_side_left",
                "ring_side_right", "ring_rear_left", "ring_rear_right")
STEREO_CAMERAS = ("stereo_front_left", "stereo_front_right")
LIDARS = ("up_lidar", "down_lidar")
WORLD_EXTRA_ARM_M = 12.0  # paint and buildings continue this far past the map edge
PARK_LATERAL = 8.3  # parked car centre from the road axis (parking strip 7 - 9.5 m)
LANE_CENTER = (LANE_W / 2, 1.5 * LANE_W)  # inner, outer lane centre offsets
LANE_CHANGE_S = 5.0
_UUID_NS = uuid.UUID("6f1c7a52-3c2e-4d0b-9a57-5e3b0f0c2a11")
CAR_COLORS = np.array([[180, 30, 30], [30, 60, 150], [200, 200, 205], [25, 25, 28], [120, 125, 130],
                       [210, 170, 40], [40, 110, 70], [235, 235, 235]], np.float32)
FACADE_COLORS = np.array([[150, 80, 60], [190, 175, 150], [120, 120, 125], [95, 110, 130], [170, 150, 120],
                          [140, 140, 110], [200, 195, 185]], np.float32)
SHIRT_COLORS = np.array([[200, 60, 60], [60, 120, 200], [230, 200, 80], [80, 160, 90]], np.float32)
REFLECTIVITY = {KIND_BUILDING: 28, KIND_VEHICLE: 45, KIND_PEDESTRIAN: 30}


def _smoothstep(u: np.ndarray) -> np.ndarray:
    u = np.clip(u, 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


@dataclass(frozen=True)
class EgoTrajectory:
    """Constant speed along +x (eastbound) with a smooth lateral move between lane centres."""

    x_start: float
    speed: float
    y_start: float
    y_end: float
    t_mid_s: float
    change_s: float

    def xy_yaw(self, t_s: np.ndarray) -> tuple[F64, F64, F64]:
        t_s = np.asarray(t_s, np.float64)
        u = (t_s - (self.t_mid_s - self.change_s / 2)) / self.change_s
        dy = self.y_end - self.y_start
        y = self.y_start + dy * _smoothstep(u)
        inside = (u > 0) & (u < 1)
        vy = np.where(inside, dy * 6.0 * u * (1.0 - u) / self.change_s, 0.0)
        return self.x_start + self.speed * t_s, y, np.arctan2(vy, self.speed)


@dataclass(frozen=True)
class ActorTrack:
    """A cuboid moving at constant velocity along its heading (speed 0: parked/standing)."""

    track_uuid: str
    category: str
    kind: int
    size_lwh: tuple[float, float, float]
    color: tuple[float, float, float]
    start_xy: tuple[float, float]  # local, at the first sweep
    heading: float
    speed: float

    def xy_at(self, t_s: float) -> F64:
        d = np.array([np.cos(self.heading), np.sin(self.heading)])
        return np.asarray(self.start_xy) + self.speed * float(t_s) * d


@dataclass(frozen=True, eq=False)
class ActorPoses:
    """Actors at one instant, in the city frame."""

    track_uuid: list[str]
    category: list[str]
    size_lwh: F64  # (K, 3)
    city_T_box: F64  # (K, 4, 4)


@dataclass(eq=False)
class SyntheticWorld:
    """Everything needed to regenerate the log and render ground truth from any viewpoint."""

    seed: int
    config: SynthConfig
    log_id: str
    city_frame: str  # e.g. "PIT_city_48213"
    origin_city: F64  # (3,) city coordinates of the local origin; [2] is the ground height
    map_layout: RoadLayout  # arms cut at the map edge (what the map JSON holds)
    world_layout: RoadLayout  # arms a bit longer (what is painted)
    buildings: BoxSet
    actors: tuple[ActorTrack, ...]
    ego: EgoTrajectory
    timeline: Timeline

    @property
    def city(self) -> str:
        return self.config.city

    @property
    def ground_z_city(self) -> float:
        return float(self.origin_city[2])

    @property
    def city_T_local(self) -> F64:
        return translation_T(*self.origin_city)

    @property
    def local_T_city(self) -> F64:
        return translation_T(*(-self.origin_city))

    @cached_property
    def rig(self) -> Rig:
        """The AV2 rig at the log's image scale (what the calibration files hold)."""
        return load_rig("av2", scale=self.config.image_scale)

    @property
    def camera_channels(self) -> list[str]:
        return list(RING_CAMERAS) + (list(STEREO_CAMERAS) if self.config.include_stereo else [])

    @cached_property
    def texture(self) -> GroundTexture:
        reach = self.world_layout.arm_length + 4.0
        return build_ground_texture(self.world_layout, reach, self.config.texture_res_m, salt=self.seed)

    def seconds_since_start(self, timestamp_ns) -> F64:
        return (np.asarray(timestamp_ns, np.int64) - np.int64(self.timeline.t0_ns)).astype(np.float64) * 1e-9

    def local_T_ego_at(self, timestamp_ns) -> F64:
        """(4, 4) for a scalar timestamp, else (M, 4, 4)."""
        t = self.seconds_since_start(timestamp_ns)
        x, y, yaw = self.ego.xy_yaw(np.atleast_1d(t))
        c, s = np.cos(yaw), np.sin(yaw)
        R = np.zeros((len(x), 3, 3))
        R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = c, -s, s, c, 1.0
        T = make_T(R, np.column_stack([x, y, np.full(len(x), EGO_ORIGIN_HEIGHT_M)]))
        return T[0] if np.ndim(timestamp_ns) == 0 else T

    def city_T_ego_at(self, timestamp_ns) -> F64:
        return self.city_T_local @ self.local_T_ego_at(timestamp_ns)

    def actor_boxes_at(self, timestamp_ns: int) -> BoxSet:
        """Actors as local-frame boxes (resting on the ground) at ``timestamp_ns``."""
        if not self.actors:
            return BoxSet.empty()
        t = float(self.seconds_since_start(timestamp_ns))
        size = np.array([a.size_lwh for a in self.actors], np.float64)
        xy = np.stack([a.xy_at(t) for a in self.actors])
        center = np.column_stack([xy, size[:, 2] / 2])
        kind = np.array([a.kind for a in self.actors], np.int8)
        return BoxSet(center, np.array([a.heading for a in self.actors]), size,
                      np.array([a.color for a in self.actors], np.float32), kind,
                      np.array([REFLECTIVITY[int(k)] for k in kind], np.uint8))

    def boxes_at(self, timestamp_ns: int) -> BoxSet:
        """Buildings then actors (actor i is box ``len(buildings) + i``)."""
        return BoxSet.concat(self.buildings, self.actor_boxes_at(timestamp_ns))

    def actor_poses_at(self, timestamp_ns: int) -> ActorPoses:
        boxes = self.actor_boxes_at(timestamp_ns)
        local_T_box = make_T(boxes.rotations, boxes.center)
        return ActorPoses([a.track_uuid for a in self.actors], [a.category for a in self.actors],
                          boxes.size.copy(), self.city_T_local[None] @ local_T_box)

    def describe(self) -> dict:
        """The JSON record written beside the log (enough to rebuild this world)."""
        return {"format": WORLD_FORMAT, "seed": self.seed, "config": self.config.to_dict(),
                "log_id": self.log_id, "city_frame": self.city_frame,
                "city_T_local_translation": self.origin_city.tolist(),
                "ego_origin_height_m": EGO_ORIGIN_HEIGHT_M, "first_sweep_ns": self.timeline.t0_ns,
                "n_sweeps": len(self.timeline.sweeps_ns)}


def _uuid4(rng: np.random.Generator) -> str:
    return str(uuid.UUID(bytes=rng.bytes(16), version=4))


def _place_buildings(rng: np.random.Generator, arm_length: float) -> BoxSet:
    """Facades along both sides of every arm, skipping lots that would overlap."""
    centers, yaws, sizes, colors = [], [], [], []
    taken: list[Polygon] = []
    for k in range(4):
        R = rot90(k)
        for side in (1.0, -1.0):
            a = INTER_HALF + 3.0 + rng.uniform(0.0, 3.0)
            while a < arm_length + 6.0:
                length, depth = rng.uniform(8.0, 20.0), rng.uniform(8.0, 14.0)
                height = rng.uniform(5.0, 22.0)
                near = DRIVABLE_HALF + SIDEWALK_W + 1.0 + rng.uniform(0.0, 2.0)
                color = FACADE_COLORS[rng.integers(len(FACADE_COLORS))] * rng.uniform(0.85, 1.1)
                c_xy = R @ np.array([-(a + length / 2), side * (near + depth / 2)])
                a += length + rng.uniform(1.0, 5.0)
                lx, ly = (length, depth) if k % 2 == 0 else (depth, length)
                foot = Polygon([(c_xy[0] - lx / 2, c_xy[1] - ly / 2), (c_xy[0] + lx / 2, c_xy[1] - ly / 2),
                                (c_xy[0] + lx / 2, c_xy[1] + ly / 2), (c_xy[0] - lx / 2, c_xy[1] + ly / 2)])
                if any(foot.intersects(t) for t in taken):
                    continue
                taken.append(foot.buffer(0.5))
                centers.append([c_xy[0], c_xy[1], height / 2])
                yaws.append(0.0)
                sizes.append([lx, ly, height])
                colors.append(np.clip(color, 0, 255))
    n = len(centers)
    return BoxSet(np.array(centers).reshape(n, 3), np.array(yaws), np.array(sizes).reshape(n, 3),
                  np.array(colors, np.float32).reshape(n, 3), np.full(n, KIND_BUILDING, np.int8),
                  np.full(n, REFLECTIVITY[KIND_BUILDING], np.uint8))


def _car(rng: np.random.Generator, xy: tuple[float, float], heading: float, speed: float) -> ActorTrack:
    size = (float(rng.uniform(4.2, 5.0)), float(rng.uniform(1.8, 2.0)), float(rng.uniform(1.45, 1.8)))
    color = tuple(float(c) for c in CAR_COLORS[rng.integers(len(CAR_COLORS))])
    return ActorTrack(_uuid4(rng), "REGULAR_VEHICLE", KIND_VEHICLE, size, color,
                      (float(xy[0]), float(xy[1])), float(heading), float(speed))


def _place_actors(rng: np.random.Generator, cfg: SynthConfig, ego: EgoTrajectory, arm_length: float,
                  duration_s: float) -> tuple[ActorTrack, ...]:
    actors: list[ActorTrack] = []
    ego_x0, ego_x1 = ego.x_start, ego.x_start + ego.speed * duration_s
    # Parked cars: slots in the parking strips, preferring those near the ego's path.
    slots = []
    for k in range(4):
        R = rot90(k)
        for side in (1.0, -1.0):
            for a in np.arange(INTER_HALF + 5.0, arm_length - 3.0, 6.5):
                xy = R @ np.array([-a, side * PARK_LATERAL])
                heading = np.arctan2(*(R @ np.array([1.0 if side < 0 else -1.0, 0.0]))[::-1])
                slots.append((xy, heading))
    if cfg.n_parked:
        dist = np.array([max(0.0, ego_x0 - xy[0], xy[0] - ego_x1) + abs(xy[1]) for xy, _ in slots])
        p = np.exp(-dist / 25.0)
        pick = rng.choice(len(slots), size=min(cfg.n_parked, len(slots)), replace=False, p=p / p.sum())
        for i in sorted(pick):
            xy, heading = slots[i]
            actors.append(_car(rng, tuple(xy), heading + rng.uniform(-0.05, 0.05), 0.0))
    # Moving cars: a lead car ahead of the ego, oncoming traffic, and cross traffic leaving the junction.
    roles = ("lead", "oncoming", "cross")
    for j in range(cfg.n_moving):
        role, rank = roles[j % 3], j // 3
        if role == "lead":
            lane_y = -LANE_CENTER[1 - rank % 2]
            xy = (ego.x_start + 25.0 + 15.0 * rank + rng.uniform(0.0, 8.0), lane_y)
            actors.append(_car(rng, xy, 0.0, ego.speed * rng.uniform(0.98, 1.05)))
        elif role == "oncoming":
            xy = (ego_x1 + 10.0 + 20.0 * rank + rng.uniform(0.0, 25.0), LANE_CENTER[rank % 2])
            actors.append(_car(rng, xy, np.pi, rng.uniform(7.0, 11.0)))
        else:
            north = rank % 2 == 0
            lane_x = LANE_CENTER[rng.integers(2)] * (1.0 if north else -1.0)
            y = (INTER_HALF + 4.0 + 12.0 * (rank // 2) + rng.uniform(0.0, 10.0)) * (1.0 if north else -1.0)
            actors.append(_car(rng, (lane_x, y), np.pi / 2 if north else -np.pi / 2, rng.uniform(5.0, 9.0)))
    for j in range(cfg.n_pedestrians):
        side = 1.0 if j % 2 == 0 else -1.0
        x = rng.uniform(ego_x0 - 5.0, ego_x1 + 20.0)
        lateral = side * (DRIVABLE_HALF + SIDEWALK_W / 2 + rng.uniform(-0.6, 0.6))
        heading = 0.0 if rng.uniform() < 0.5 else np.pi
        size = (float(rng.uniform(0.5, 0.7)), float(rng.uniform(0.5, 0.7)), float(rng.uniform(1.6, 1.9)))
        color = tuple(float(c) for c in SHIRT_COLORS[rng.integers(len(SHIRT_COLORS))])
        actors.append(ActorTrack(_uuid4(rng), "PEDESTRIAN", KIND_PEDESTRIAN, size, color, (float(x), lateral),
                                 heading, float(rng.uniform(1.1, 1.5))))
    return tuple(actors)


def build_world(seed: int = 0, config: SynthConfig | None = None) -> SyntheticWorld:
    """The world for ``seed`` (layout, actors, offsets, timestamps) at ``config``'s scale."""
    cfg = config or SynthConfig()
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    seed = int(seed)
    key = (seed, cfg)
    if key in _CACHE:
        return _CACHE[key]
    rng = np.random.default_rng(seed)
    origin = np.array([float(rng.integers(2500, 6000)), float(rng.integers(1000, 4000)),
                       0.25 * float(rng.integers(80, 240))])
    city_frame = f"{cfg.city}_city_{int(rng.integers(10000, 99999))}"
    n = cfg.n_sweeps
    duration = n * 0.1
    speed = float(cfg.ego_speed_mps) if cfg.ego_speed_mps is not None else float(rng.uniform(8.0, 10.0))
    y_end = -LANE_CENTER[1] if cfg.lane_change else -LANE_CENTER[0]
    ego = EgoTrajectory(-speed * duration / 2, speed, -LANE_CENTER[0], y_end, duration / 2, LANE_CHANGE_S)
    arm = arm_length_for(speed * duration / 2 + cfg.map_margin_m)
    map_layout = build_road_layout(arm)
    world_layout = build_road_layout(arm + WORLD_EXTRA_ARM_M)
    buildings = _place_buildings(rng, world_layout.arm_length)
    actors = _place_actors(rng, cfg, ego, arm, duration)
    channels = list(RING_CAMERAS) + (list(STEREO_CAMERAS) if cfg.include_stereo else [])
    timeline = make_timeline(rng, n, channels)
    identity = {"seed": seed, "config": cfg.to_dict(), "version": GENERATOR_VERSION}
    log_id = str(uuid.uuid5(_UUID_NS, json.dumps(identity, sort_keys=True)))
    world = SyntheticWorld(seed, cfg, log_id, city_frame, origin, map_layout, world_layout, buildings, actors,
                           ego, timeline)
    if len(_CACHE) >= _CACHE_MAX:
        _CACHE.pop(next(iter(_CACHE)))
    _CACHE[key] = world
    return world


_CACHE: dict[tuple[int, SynthConfig], SyntheticWorld] = {}
_CACHE_MAX = 4


def clear_world_cache() -> None:
    """Forget built worlds (each keeps its ground texture, tens of MB)."""
    _CACHE.clear()


def load_world(log_dir: str | Path) -> SyntheticWorld:
    """Rebuild the world of a synthetic log from its ``synthetic_world.json``."""
    path = Path(log_dir) / WORLD_FILE
    if not path.is_file():
        raise FileNotFoundError(f"{path}: not found; {log_dir} is not a synthetic log written by nuav2")
    try:
        rec = json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise ValueError(f"{path}: not valid JSON ({e})") from e
    if not isinstance(rec, dict) or rec.get("format") != WORLD_FORMAT:
        raise ValueError(f"{path}: field 'format' must be {WORLD_FORMAT!r}")
    for key in ("seed", "config", "log_id"):
        if key not in rec:
            raise ValueError(f"{path}: missing field '{key}'")
    try:
        cfg = SynthConfig.from_dict(rec["config"], str(path))
        world = build_world(rec["seed"], cfg)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{path}: bad seed/config ({e})") from e
    if world.log_id != rec["log_id"]:
        raise ValueError(f"{path}: log_id {rec['log_id']!r} does not match the world rebuilt from its seed "
                         f"and config ({world.log_id!r}); the generator changed since the log was written")
    return world
