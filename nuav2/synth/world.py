"""SyntheticWorld: the procedural, seed-deterministic scene behind a synthetic AV2 log.

It holds the road layout, buildings, street furniture, actor tracks, the ego trajectory, the
terrain, the sun and sky, and the sensor timeline, all analytic in continuous time, so any
sensor (the log's own, or another rig at any pose) can be rendered from it. Geometry lives in
a *local* frame (origin on the ground at the layout's centre, x east, y north);
``city_T_local`` is a pure translation by km-scale offsets and a non-zero ground height, so
downstream float32 recentring is exercised. The ego origin rides ``EGO_ORIGIN_HEIGHT_M`` above
the ground under its rear axle, pitched and rolled by the terrain under its wheels.

Which parts exist depends on the config's realism factors (config.py); the ``easy`` world is
built by exactly the original code path and random draws (legacy.py), and each factor draws
from its own random stream, so switching one factor on changes only what that factor adds.
"""

from __future__ import annotations

import json
import uuid
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np

from nuav2.geometry import F64, make_T, translation_T
from nuav2.rig import Rig, load_rig
from nuav2.synth.boxes import KIND_VEHICLE, BoxSet
from nuav2.synth.config import LAYOUTS, SynthConfig
from nuav2.synth.layouts import StreetPlan, build_plan, draw_params, plan_layout
from nuav2.synth.legacy import (
    LANE_CENTER,
    LANE_CHANGE_S,
    ActorTrack,
    EgoTrajectory,
    place_actors,
    place_buildings,
)
from nuav2.synth.light import Sky, make_sky
from nuav2.synth.materials import REFLECTIVITY
from nuav2.synth.motion import PathMotion, ego_motion
from nuav2.synth.road import RoadLayout, arm_length_for, build_road_layout
from nuav2.synth.shapes import cyclist, pedestrian, vehicle
from nuav2.synth.terrain import Terrain, build_terrain, flat_terrain
from nuav2.synth.texture import GroundTexture, build_ground_texture, build_tiled_texture
from nuav2.synth.timeline import Timeline, make_timeline

WORLD_FILE = "synthetic_world.json"
WORLD_FORMAT = "nuav2-synthetic/1"
GENERATOR_VERSION = 1  # bump when the same seed and config would give a different world
EGO_ORIGIN_HEIGHT_M = 0.32
EGO_WHEELBASE_M, EGO_TRACK_M = 2.85, 1.6
RING_CAMERAS = ("ring_front_center", "ring_front_left", "ring_front_right", "ring_side_left",
                "ring_side_right", "ring_rear_left", "ring_rear_right")
STEREO_CAMERAS = ("stereo_front_left", "stereo_front_right")
LIDARS = ("up_lidar", "down_lidar")
WORLD_EXTRA_ARM_M = 12.0  # paint and buildings continue this far past the map edge
TERRAIN_MARGIN_M = 40.0
_UUID_NS = uuid.UUID("6f1c7a52-3c2e-4d0b-9a57-5e3b0f0c2a11")
# Independent random streams of the factors (np.random.default_rng([seed, stream])).
STREAM_LAYOUT, STREAM_TERRAIN, STREAM_SKY, STREAM_CONTENT, STREAM_PLACE, STREAM_TIME = 1, 2, 3, 4, 5, 6
VEHICLE_BODIES = ("car", "suv", "bus", "truck")


def stream(seed: int, which: int) -> np.random.Generator:
    return np.random.default_rng([seed, which])


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
    map_layout: RoadLayout  # roads cut at the map edge (what the map JSON holds)
    world_layout: RoadLayout  # roads a bit longer (what is painted)
    buildings: BoxSet
    actors: tuple[ActorTrack, ...]
    ego: EgoTrajectory | PathMotion
    timeline: Timeline
    terrain: Terrain = field(default_factory=flat_terrain)
    sky: Sky = field(default_factory=lambda: make_sky(None))
    furniture: BoxSet = field(default_factory=BoxSet.empty)
    plan: StreetPlan | None = None
    layout_name: str = "four_way"
    manoeuvre: str = "cruise"

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
        if self.layout_name == "four_way":
            reach = self.world_layout.arm_length + 4.0
            return build_ground_texture(self.world_layout, reach, self.config.texture_res_m, salt=self.seed)
        return build_tiled_texture(self.world_layout, self.config.texture_res_m, salt=self.seed)

    @cached_property
    def statics(self) -> BoxSet:
        """Buildings, then street furniture."""
        return BoxSet.concat(self.buildings, self.furniture) if len(self.furniture) else self.buildings

    def seconds_since_start(self, timestamp_ns) -> F64:
        return (np.asarray(timestamp_ns, np.int64) - np.int64(self.timeline.t0_ns)).astype(np.float64) * 1e-9

    def ego_xy_yaw(self, t_s: F64) -> tuple[F64, F64]:
        """(M, 2) rear-axle ground positions and (M,) headings at seconds since the start."""
        if isinstance(self.ego, EgoTrajectory):
            x, y, yaw = self.ego.xy_yaw(t_s)
            return np.column_stack([x, y]), yaw
        return self.ego.xy_yaw(t_s)

    def local_T_ego_at(self, timestamp_ns) -> F64:
        """(4, 4) for a scalar timestamp, else (M, 4, 4)."""
        t = self.seconds_since_start(timestamp_ns)
        xy, yaw = self.ego_xy_yaw(np.atleast_1d(t))
        if self.terrain.flat:
            c, s = np.cos(yaw), np.sin(yaw)
            R = np.zeros((len(yaw), 3, 3))
            R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = c, -s, s, c, 1.0
            z = np.full(len(yaw), EGO_ORIGIN_HEIGHT_M)
        else:
            R, z = tilt_on(self.terrain, xy, yaw, 0.0, EGO_WHEELBASE_M, EGO_TRACK_M)
            z = z + EGO_ORIGIN_HEIGHT_M
        T = make_T(R, np.column_stack([xy[:, 0], xy[:, 1], z]))
        return T[0] if np.ndim(timestamp_ns) == 0 else T

    def city_T_ego_at(self, timestamp_ns) -> F64:
        return self.city_T_local @ self.local_T_ego_at(timestamp_ns)

    def actor_boxes_at(self, timestamp_ns: int) -> BoxSet:
        """Actors' cuboids in the local frame at ``timestamp_ns`` (resting on the ground; vehicles
        pitched and rolled by the terrain), owned by their actor index."""
        if not self.actors:
            return BoxSet.empty()
        t = float(self.seconds_since_start(timestamp_ns))
        size = np.array([a.size_lwh for a in self.actors], np.float64)
        poses = [a.xy_yaw_at(t) for a in self.actors]
        xy = np.stack([p[0] for p in poses])
        yaw = np.array([p[1] for p in poses])
        kind = np.array([a.kind for a in self.actors], np.int8)
        color = np.array([a.color for a in self.actors], np.float32)
        refl = np.array([REFLECTIVITY[int(k)] for k in kind], np.uint8)
        owner = np.arange(len(self.actors), dtype=np.int64)
        if self.terrain.flat:
            center = np.column_stack([xy, size[:, 2] / 2])
            return BoxSet(center, yaw, size, color, kind, refl, owner=owner)
        rot = np.zeros((len(yaw), 3, 3))
        center = np.zeros((len(yaw), 3))
        tilted = np.array([a.kind == KIND_VEHICLE or a.body in VEHICLE_BODIES for a in self.actors])
        for i in np.flatnonzero(tilted):
            wheelbase = 0.62 * size[i, 0]
            R, z = tilt_on(self.terrain, xy[i:i + 1], yaw[i:i + 1], 0.5 * wheelbase, wheelbase,
                           size[i, 1] - 0.25, centred=True)
            rot[i] = R[0]
            center[i] = np.array([*xy[i], z[0]]) + R[0][:, 2] * size[i, 2] / 2
        up = np.flatnonzero(~tilted)
        if len(up):
            c, s = np.cos(yaw[up]), np.sin(yaw[up])
            rot[up, 0, 0], rot[up, 0, 1], rot[up, 1, 0], rot[up, 1, 1], rot[up, 2, 2] = c, -s, s, c, 1.0
            center[up] = np.column_stack([xy[up], self.terrain.height(xy[up]) + size[up, 2] / 2])
        return BoxSet(center, yaw, size, color, kind, refl, rot=rot, owner=owner)

    def actor_solids_at(self, timestamp_ns: int) -> BoxSet:
        """What the actors look like: the cuboid itself (body "box") or their shaped solids."""
        boxes = self.actor_boxes_at(timestamp_ns)
        if all(a.body == "box" for a in self.actors):
            return boxes
        t = float(self.seconds_since_start(timestamp_ns))
        parts = []
        for i, a in enumerate(self.actors):
            if a.body == "box":
                parts.append(boxes.subset(np.array([i])))
                continue
            local_T_box = make_T(boxes.rotations[i], boxes.center[i])
            size = np.asarray(a.size_lwh)
            if a.body in VEHICLE_BODIES:
                solids = vehicle(a.body, size, np.asarray(a.color))
            elif a.body == "pedestrian":
                solids = pedestrian(size, np.asarray(a.color), a.distance_at(t), a.phase)
            else:
                solids = cyclist(size, np.asarray(a.color), np.asarray(a.accent), a.distance_at(t))
            parts.append(solids.boxset(local_T_box, i))
        return BoxSet.concat(*parts)

    def boxes_at(self, timestamp_ns: int) -> BoxSet:
        """Every solid at ``timestamp_ns``: buildings, furniture, then the actors' (``owner`` >= 0)."""
        cache = self.__dict__.setdefault("_boxes_cache", {})
        key = int(timestamp_ns)
        if key not in cache:
            if len(cache) >= 32:
                cache.pop(next(iter(cache)))
            cache[key] = BoxSet.concat(self.statics, self.actor_solids_at(key))
        return cache[key]

    def actor_poses_at(self, timestamp_ns: int) -> ActorPoses:
        boxes = self.actor_boxes_at(timestamp_ns)
        local_T_box = make_T(boxes.rotations, boxes.center)
        return ActorPoses([a.track_uuid for a in self.actors], [a.category for a in self.actors],
                          boxes.size.copy(), self.city_T_local[None] @ local_T_box)

    def describe(self) -> dict:
        """The JSON record written beside the log (enough to rebuild this world)."""
        rec = {"format": WORLD_FORMAT, "seed": self.seed, "config": self.config.to_dict(),
               "log_id": self.log_id, "city_frame": self.city_frame,
               "city_T_local_translation": self.origin_city.tolist(),
               "ego_origin_height_m": EGO_ORIGIN_HEIGHT_M, "first_sweep_ns": self.timeline.t0_ns,
               "n_sweeps": len(self.timeline.sweeps_ns)}
        if self.config.factors or self.config.layout is not None:
            rec.update({"layout": self.layout_name, "manoeuvre": self.manoeuvre,
                        "factors": sorted(self.config.factors)})
        return rec


def tilt_on(terrain: Terrain, xy: F64, yaw: F64, back_m: float, wheelbase: float, track: float,
            centred: bool = False) -> tuple[F64, F64]:
    """(M, 3, 3) rotations and (M,) ground heights of vehicles whose wheels rest on the relief.

    The rear axle is ``back_m`` behind ``xy`` (``centred``: ``xy`` is mid-wheelbase and the height
    is the mean of the four wheels, else the rear axle's); pitch from the axles' heights over the
    wheelbase, roll from the sides' heights over the track."""
    f = np.column_stack([np.cos(yaw), np.sin(yaw)])
    left = np.column_stack([-f[:, 1], f[:, 0]])
    rear = xy - back_m * f
    pts = np.stack([rear + 0.5 * track * left, rear - 0.5 * track * left,
                    rear + wheelbase * f + 0.5 * track * left, rear + wheelbase * f - 0.5 * track * left], 1)
    h = terrain.relief(pts.reshape(-1, 2)).reshape(-1, 4)
    z_rear, z_front = h[:, :2].mean(1), h[:, 2:].mean(1)
    z_left, z_right = h[:, [0, 2]].mean(1), h[:, [1, 3]].mean(1)
    pitch = np.arctan2(z_front - z_rear, wheelbase)
    roll = np.arctan2(z_left - z_right, track)
    cy, sy, cp, sp = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch)
    cr, sr = np.cos(roll), np.sin(roll)
    # R = Rz(yaw) @ Ry(-pitch) @ Rx(roll): nose up on an uphill grade, left side up when the left is higher.
    R = np.zeros((len(yaw), 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 0, 2] = cy * cp, -cy * sp * sr - sy * cr, -cy * sp * cr + sy * sr
    R[:, 1, 0], R[:, 1, 1], R[:, 1, 2] = sy * cp, -sy * sp * sr + cy * cr, -sy * sp * cr - cy * sr
    R[:, 2, 0], R[:, 2, 1], R[:, 2, 2] = sp, cp * sr, cp * cr
    return R, (h.mean(1) if centred else z_rear)


def world_log_id(seed: int, cfg: SynthConfig) -> str:
    """The log id of the world of ``seed`` and ``cfg``, without building it (finding logs already written)."""
    identity = {"seed": seed, "config": cfg.to_dict(), "version": GENERATOR_VERSION}
    return str(uuid.uuid5(_UUID_NS, json.dumps(identity, sort_keys=True)))


def build_world(seed: int = 0, config: SynthConfig | None = None) -> SyntheticWorld:
    """The world for ``seed`` (layout, actors, offsets, timestamps) at ``config``'s scale and realism."""
    cfg = config or SynthConfig()
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    seed = int(seed)
    key = (seed, cfg)
    if key in _CACHE:
        return _CACHE[key]
    from nuav2.synth import buildings as buildings_mod
    from nuav2.synth import placement

    rng = np.random.default_rng(seed)
    origin = np.array([float(rng.integers(2500, 6000)), float(rng.integers(1000, 4000)),
                       0.25 * float(rng.integers(80, 240))])
    city_frame = f"{cfg.city}_city_{int(rng.integers(10000, 99999))}"
    n = cfg.n_sweeps
    duration = n * 0.1
    channels = list(RING_CAMERAS) + (list(STEREO_CAMERAS) if cfg.include_stereo else [])
    lrng = stream(seed, STREAM_LAYOUT)
    name = cfg.layout or (LAYOUTS[int(lrng.integers(len(LAYOUTS)))] if cfg.layouts else "four_way")
    manoeuvre = "cruise"
    if name == "four_way" and not cfg.layouts:
        # The original world: the same draws from the seed's stream, in the same order.
        speed = float(cfg.ego_speed_mps) if cfg.ego_speed_mps is not None else float(rng.uniform(8.0, 10.0))
        y_end = -LANE_CENTER[1] if cfg.lane_change else -LANE_CENTER[0]
        ego = EgoTrajectory(-speed * duration / 2, speed, -LANE_CENTER[0], y_end, duration / 2, LANE_CHANGE_S)
        arm = arm_length_for(speed * duration / 2 + cfg.map_margin_m)
        map_layout = build_road_layout(arm)
        world_layout = build_road_layout(arm + WORLD_EXTRA_ARM_M)
        buildings = place_buildings(rng, world_layout.arm_length)
        actors = place_actors(rng, cfg, ego, arm, duration)
        timeline = make_timeline(rng, n, channels)
        plan = build_plan("four_way", arm + WORLD_EXTRA_ARM_M, {})
        if cfg.content:
            actors = placement.dress_legacy_actors(actors, stream(seed, STREAM_CONTENT))
    else:
        params = draw_params(name, lrng)
        if cfg.ego_speed_mps is not None:
            speed = float(cfg.ego_speed_mps)
        else:
            speed = float(lrng.uniform(7.0, 13.0) if cfg.layouts else lrng.uniform(8.0, 10.0))
        if name == "curved":
            speed = min(speed, 10.0)
        reach = speed * duration / 2 + cfg.map_margin_m + 45.0
        plan = build_plan(name, reach + WORLD_EXTRA_ARM_M, params)
        map_layout = plan_layout(build_plan(name, reach, params))
        world_layout = plan_layout(plan)
        ego, manoeuvre = ego_motion(world_layout, plan, lrng, duration, speed, cfg.layouts, cfg.lane_change)
        prng = stream(seed, STREAM_PLACE)
        buildings = buildings_mod.place_buildings(plan, world_layout, prng)
        actors = placement.place_actors(prng, cfg, plan, world_layout, ego, duration)
        timeline = make_timeline(stream(seed, STREAM_TIME), n, channels)
    terrain = flat_terrain()
    if cfg.relief or cfg.content:
        half = max(float(np.max(np.abs(np.concatenate([r for _, r in world_layout.drivable_areas])))), 50.0)
        axes = [r.centre for r in plan.roads]
        terrain = build_terrain(stream(seed, STREAM_TERRAIN), half + TERRAIN_MARGIN_M,
                                world_layout.drivable_union(), axes, plan.crown_half, cfg.relief, cfg.content)
    furniture = BoxSet.empty()
    if cfg.content:
        crng = stream(seed, STREAM_CONTENT + 10)
        actors = actors + placement.place_cyclists(crng, cfg, world_layout, ego, duration, actors)
        furniture = placement.place_furniture(crng, plan, world_layout, terrain)
        buildings = buildings_mod.style_facades(buildings, crng)
    buildings = buildings_mod.settle(buildings, terrain, sink_m=0.5)
    sky = make_sky(stream(seed, STREAM_SKY) if cfg.shadows else None)
    log_id = world_log_id(seed, cfg)
    world = SyntheticWorld(seed, cfg, log_id, city_frame, origin, map_layout, world_layout, buildings, actors,
                           ego, timeline, terrain, sky, furniture, plan, name, manoeuvre)
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
