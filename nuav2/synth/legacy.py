"""The original world's ego and actors (the ``easy`` preset), kept draw for draw.

These functions consume the seed's random stream in the original order (buildings, then actors),
so an easy world -- and every byte of its log -- is what it was before the realism presets.
"""

from __future__ import annotations

import uuid
from dataclasses import dataclass

import numpy as np
from shapely.geometry import Polygon

from nuav2.geometry import F64
from nuav2.synth.boxes import KIND_BUILDING, KIND_PEDESTRIAN, KIND_VEHICLE, BoxSet
from nuav2.synth.config import SynthConfig
from nuav2.synth.materials import REFLECTIVITY
from nuav2.synth.road import DRIVABLE_HALF, INTER_HALF, LANE_W, SIDEWALK_W, rot90

PARK_LATERAL = 8.3  # parked car centre from the road axis (parking strip 7 - 9.5 m)
LANE_CENTER = (LANE_W / 2, 1.5 * LANE_W)  # inner, outer lane centre offsets
LANE_CHANGE_S = 5.0
CAR_COLORS = np.array([[180, 30, 30], [30, 60, 150], [200, 200, 205], [25, 25, 28], [120, 125, 130],
                       [210, 170, 40], [40, 110, 70], [235, 235, 235]], np.float32)
FACADE_COLORS = np.array([[150, 80, 60], [190, 175, 150], [120, 120, 125], [95, 110, 130], [170, 150, 120],
                          [140, 140, 110], [200, 195, 185]], np.float32)
SHIRT_COLORS = np.array([[200, 60, 60], [60, 120, 200], [230, 200, 80], [80, 160, 90]], np.float32)


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
    """An actor: a cuboid moving at constant velocity along its heading (speed 0: parked/standing),
    or, with ``motion``, along a path. ``body`` names its shape ("box": the cuboid itself, else a
    shapes.py class); ``phase`` and ``accent`` vary gait and secondary colours."""

    track_uuid: str
    category: str
    kind: int
    size_lwh: tuple[float, float, float]
    color: tuple[float, float, float]
    start_xy: tuple[float, float]  # local, at the first sweep
    heading: float
    speed: float
    body: str = "box"
    motion: object = None  # motion.PathMotion
    phase: float = 0.0
    accent: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def xy_at(self, t_s: float) -> F64:
        d = np.array([np.cos(self.heading), np.sin(self.heading)])
        return np.asarray(self.start_xy) + self.speed * float(t_s) * d

    def xy_yaw_at(self, t_s: float) -> tuple[F64, float]:
        if self.motion is None:
            return self.xy_at(t_s), self.heading
        xy, yaw = self.motion.xy_yaw(np.array([float(t_s)]))
        return xy[0], float(yaw[0])

    def distance_at(self, t_s: float) -> float:
        """Distance travelled since the log start (drives gait and pedalling)."""
        if self.motion is None:
            return self.speed * float(t_s)
        return float(np.interp(t_s, self.motion.t, self.motion.s) - self.motion.s[0])


def uuid4(rng: np.random.Generator) -> str:
    return str(uuid.UUID(bytes=rng.bytes(16), version=4))


def place_buildings(rng: np.random.Generator, arm_length: float) -> BoxSet:
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


def car(rng: np.random.Generator, xy: tuple[float, float], heading: float, speed: float) -> ActorTrack:
    size = (float(rng.uniform(4.2, 5.0)), float(rng.uniform(1.8, 2.0)), float(rng.uniform(1.45, 1.8)))
    color = tuple(float(c) for c in CAR_COLORS[rng.integers(len(CAR_COLORS))])
    return ActorTrack(uuid4(rng), "REGULAR_VEHICLE", KIND_VEHICLE, size, color,
                      (float(xy[0]), float(xy[1])), float(heading), float(speed))


def place_actors(rng: np.random.Generator, cfg: SynthConfig, ego: EgoTrajectory, arm_length: float,
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
            actors.append(car(rng, tuple(xy), heading + rng.uniform(-0.05, 0.05), 0.0))
    # Moving cars: a lead car ahead of the ego, oncoming traffic, and cross traffic leaving the junction.
    roles = ("lead", "oncoming", "cross")
    for j in range(cfg.n_moving):
        role, rank = roles[j % 3], j // 3
        if role == "lead":
            lane_y = -LANE_CENTER[1 - rank % 2]
            xy = (ego.x_start + 25.0 + 15.0 * rank + rng.uniform(0.0, 8.0), lane_y)
            actors.append(car(rng, xy, 0.0, ego.speed * rng.uniform(0.98, 1.05)))
        elif role == "oncoming":
            xy = (ego_x1 + 10.0 + 20.0 * rank + rng.uniform(0.0, 25.0), LANE_CENTER[rank % 2])
            actors.append(car(rng, xy, np.pi, rng.uniform(7.0, 11.0)))
        else:
            north = rank % 2 == 0
            lane_x = LANE_CENTER[rng.integers(2)] * (1.0 if north else -1.0)
            y = (INTER_HALF + 4.0 + 12.0 * (rank // 2) + rng.uniform(0.0, 10.0)) * (1.0 if north else -1.0)
            actors.append(car(rng, (lane_x, y), np.pi / 2 if north else -np.pi / 2, rng.uniform(5.0, 9.0)))
    for j in range(cfg.n_pedestrians):
        side = 1.0 if j % 2 == 0 else -1.0
        x = rng.uniform(ego_x0 - 5.0, ego_x1 + 20.0)
        lateral = side * (DRIVABLE_HALF + SIDEWALK_W / 2 + rng.uniform(-0.6, 0.6))
        heading = 0.0 if rng.uniform() < 0.5 else np.pi
        size = (float(rng.uniform(0.5, 0.7)), float(rng.uniform(0.5, 0.7)), float(rng.uniform(1.6, 1.9)))
        color = tuple(float(c) for c in SHIRT_COLORS[rng.integers(len(SHIRT_COLORS))])
        actors.append(ActorTrack(uuid4(rng), "PEDESTRIAN", KIND_PEDESTRIAN, size, color, (float(x), lateral),
                                 heading, float(rng.uniform(1.1, 1.5))))
    return tuple(actors)


