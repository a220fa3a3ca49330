"""Static LiDAR points around a time, in the city frame: the depth proxy's view of everything off the ground.

Each sweep (ego frame, motion-compensated) is moved into the city frame with the ego pose at its
timestamp; points inside annotated boxes (posed at that sweep) are dropped, because boxes carry
the actors themselves and a moving actor's points would smear along its path; points on the ego
vehicle's own body are dropped too, and so are points on the ground (the ground layer already
has them exactly, and they are half of all returns). A point's disk radius is its footprint:
range from the sensor times the lidar's angular step.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from nuav2.geometry import F64, T_inverse, transform_points
from nuav2.scene import SceneLog
from nuav2.warp._kernels import inside_boxes_kernel
from nuav2.warp.depth_proxy import GroundSurface
from nuav2.warp.tracks import BoxTracks


@dataclass(frozen=True)
class CloudConfig:
    window_ns: int = 500_000_000  # sweeps within +- this of the query time are aggregated
    angular_step_rad: float = 0.01  # lidar beam spacing: disk radius = range * step (x 0.75)
    min_radius_m: float = 0.03
    box_margin_m: float = 0.25  # boxes are grown by this when removing actor points
    ego_box_min: tuple[float, float, float] = (-1.2, -1.1, 0.05)  # ego body, metres (z above ground)
    ego_box_max: tuple[float, float, float] = (4.0, 1.1, 2.0)
    ground_band_m: float = 0.15  # points this close to the ground surface are dropped (0: keep all)
    cache_sweeps: int = 160  # a 15 s AV2 log has 150 sweeps: keep them all (~1.6 MB each on real sweeps)


def inside_boxes(points: F64, box_T_frame: F64, lo: F64, hi: F64) -> np.ndarray:
    """(B, N) bool: point n (frame coordinates) lies within ``lo[b] <= box_T_frame[b] p <= hi[b]`` (faces
    inclusive). One compiled pass per box: the numpy version spent most of a sweep's time here."""
    box_T_frame = np.ascontiguousarray(np.asarray(box_T_frame, np.float64).reshape(-1, 4, 4))
    out = np.zeros((len(box_T_frame), len(points)), bool)
    if len(points) and len(box_T_frame):
        inside_boxes_kernel(np.ascontiguousarray(points, np.float64), box_T_frame,
                            np.ascontiguousarray(np.broadcast_to(lo, (len(box_T_frame), 3)), np.float64),
                            np.ascontiguousarray(np.broadcast_to(hi, (len(box_T_frame), 3)), np.float64), out)
    return out


def points_in_boxes(points: F64, city_T_box: F64, size_lwh: F64, margin_m: float) -> np.ndarray:
    """(N,) bool: inside any of the (B) boxes grown by ``margin_m`` on every side."""
    half = 0.5 * np.asarray(size_lwh, np.float64).reshape(-1, 3) + margin_m
    return inside_boxes(points, T_inverse(np.asarray(city_T_box, np.float64).reshape(-1, 4, 4)), -half,
                        half).any(axis=0)


class LidarCloud:
    """Per-sweep static city points (cached) and their aggregation over a time window."""

    def __init__(self, scene: SceneLog, tracks: BoxTracks, config: CloudConfig | None = None,
                 ground_at: Callable[[int], GroundSurface] | None = None) -> None:
        self.scene = scene
        self.tracks = tracks
        self.config = config or CloudConfig()
        self.ground_at = ground_at
        self.sweep_ns = scene.sweep_timestamps_ns
        self._cache: OrderedDict[int, tuple[F64, F64]] = OrderedDict()
        self._windows: OrderedDict[tuple[int, int], tuple[F64, F64]] = OrderedDict()

    def sweep_points(self, index: int) -> tuple[F64, F64]:
        """(N, 3) static city points of sweep ``index`` and their (N,) disk radii."""
        if index in self._cache:
            self._cache.move_to_end(index)
            return self._cache[index]
        cfg = self.config
        ref = self.scene.lidar_sweeps[index]
        xyz_ego = np.asarray(self.scene.sweep(ref).xyz_ego, dtype=np.float64).reshape(-1, 3)
        xyz_ego = xyz_ego[np.all(np.isfinite(xyz_ego), axis=1)]
        lo = np.array(cfg.ego_box_min) - [0, 0, self.scene.rig.origin_height_m]
        hi = np.array(cfg.ego_box_max) - [0, 0, self.scene.rig.origin_height_m]
        xyz_ego = xyz_ego[~np.all((xyz_ego >= lo) & (xyz_ego <= hi), axis=1)]
        sensors = [lid.ego_T_lidar[:3, 3] for lid in self.scene.rig.lidars] or [np.zeros(3)]
        sensor = np.mean(sensors, axis=0)
        radius = np.maximum(np.linalg.norm(xyz_ego - sensor, axis=1) * cfg.angular_step_rad * 0.75,
                            cfg.min_radius_m)
        city_T_ego = self.scene.city_T_ego_at(int(ref.timestamp_ns))
        xyz_city = transform_points(city_T_ego, xyz_ego)
        if self.ground_at is not None and cfg.ground_band_m > 0 and len(xyz_city):
            ground = self.ground_at(int(ref.timestamp_ns))
            off_ground = np.abs(xyz_city[:, 2] - ground.height(xyz_city[:, :2])) > cfg.ground_band_m
            xyz_city, radius = xyz_city[off_ground], radius[off_ground]
        boxes = self.tracks.at(int(ref.timestamp_ns))
        if len(boxes):
            keep = ~points_in_boxes(xyz_city, boxes.city_T_box, boxes.size_lwh, cfg.box_margin_m)
            xyz_city, radius = xyz_city[keep], radius[keep]
        self._cache[index] = (xyz_city, radius)
        while len(self._cache) > cfg.cache_sweeps:
            self._cache.popitem(last=False)
        return xyz_city, radius

    def sweeps_near(self, timestamp_ns: int) -> tuple[int, int]:
        """Half-open index range of the sweeps within the window around ``timestamp_ns``."""
        t = int(timestamp_ns)
        lo = int(np.searchsorted(self.sweep_ns, t - self.config.window_ns, side="left"))
        hi = int(np.searchsorted(self.sweep_ns, t + self.config.window_ns, side="right"))
        if lo >= hi and len(self.sweep_ns):  # no sweep in the window: use the nearest one
            j = int(np.argmin(np.abs(self.sweep_ns - t)))
            lo, hi = j, j + 1
        return lo, hi

    def around(self, timestamp_ns: int) -> tuple[F64, F64]:
        """Aggregated static points and radii of the sweeps near ``timestamp_ns``."""
        lo, hi = self.sweeps_near(timestamp_ns)
        if lo >= hi or self.scene.load_lidar is None:
            return np.zeros((0, 3)), np.zeros(0)
        if (lo, hi) in self._windows:
            self._windows.move_to_end((lo, hi))
            return self._windows[(lo, hi)]
        parts = [self.sweep_points(i) for i in range(lo, hi)]
        out = np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])
        self._windows[(lo, hi)] = out
        while len(self._windows) > 4:  # a target time and its sources' times use a few windows
            self._windows.popitem(last=False)
        return out
