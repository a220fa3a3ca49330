"""SceneLog: the one contract between source readers (``converters/``) and everything downstream.

A reader fills it once per log; the nuScenes writer, the reconstruction and the warp renderer
read only this. Geometry is float64 in the source's metric *city* frame; lidar points are
loaded lazily because a log holds ~15M of them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np

from nuav2.geometry import F64, PoseTable
from nuav2.rig import Rig


@dataclass(frozen=True)
class LidarPoints:
    """One sweep in the source ego frame at the sweep timestamp (motion-compensated)."""

    xyz_ego: F64  # (N, 3) float64
    intensity: np.ndarray  # (N,) float32
    laser_number: np.ndarray  # (N,) uint8 (ring index)


@dataclass(frozen=True)
class LidarSweepRef:
    timestamp_ns: int
    path: Path


@dataclass(frozen=True)
class CameraFrame:
    """One image of one camera; ``timestamp_ns`` is the image's own capture time."""

    channel: str
    timestamp_ns: int
    path: Path


@dataclass(frozen=True)
class Annotations:
    """Cuboid tracks, columnar. Box poses are in the ego frame at ``timestamp_ns`` (a sweep time).

    Box frame: x along length, y along width, z up, origin at the box centre.
    """

    timestamp_ns: np.ndarray  # (K,) int64
    track_id: np.ndarray  # (K,) str (object)
    category: np.ndarray  # (K,) str (object), source category names
    size_lwh: F64  # (K, 3) length, width, height
    ego_q_box: F64  # (K, 4) wxyz
    ego_t_box: F64  # (K, 3)
    num_interior_pts: np.ndarray  # (K,) int64

    def __len__(self) -> int:
        return len(self.timestamp_ns)

    def at(self, timestamp_ns: int) -> np.ndarray:
        """Row indices annotated at exactly this sweep timestamp."""
        return np.flatnonzero(self.timestamp_ns == timestamp_ns)

    @staticmethod
    def empty() -> Annotations:
        return Annotations(np.zeros(0, np.int64), np.zeros(0, object), np.zeros(0, object), np.zeros((0, 3)),
                           np.zeros((0, 4)), np.zeros((0, 3)), np.zeros(0, np.int64))


@dataclass(frozen=True)
class LaneSegment:
    """A lane with its two boundaries in the city frame, following the travel direction."""

    id: int
    left_boundary: F64  # (N, 3)
    right_boundary: F64  # (M, 3)
    left_mark_type: str
    right_mark_type: str
    is_intersection: bool
    lane_type: str
    successors: tuple[int, ...]
    predecessors: tuple[int, ...]
    left_neighbor_id: int | None
    right_neighbor_id: int | None


@dataclass(frozen=True)
class PedCrossing:
    id: int
    edge1: F64  # (2, 3)
    edge2: F64  # (2, 3)

    @property
    def polygon(self) -> F64:
        """Ring e1[0], e1[1], e2[1], e2[0] (not closed)."""
        return np.stack([self.edge1[0], self.edge1[1], self.edge2[1], self.edge2[0]])


@dataclass(frozen=True)
class DrivableArea:
    id: int
    boundary: F64  # (N, 3), not closed


@dataclass(frozen=True)
class VectorMap:
    """The log's vector map in the city frame (AV2 semantics)."""

    city_name: str
    lane_segments: dict[int, LaneSegment]
    ped_crossings: dict[int, PedCrossing]
    drivable_areas: dict[int, DrivableArea]


@dataclass(frozen=True)
class GroundHeightRaster:
    """City-frame ground height: value = heights[int(py), int(px)] with p = s*(R xy + t)."""

    heights: np.ndarray  # (H, W) float, NaN outside the region of interest
    R: F64  # (2, 2)
    t: F64  # (2,)
    s: float

    @cached_property
    def top(self) -> float:
        """Highest finite height (``-inf`` if none): no ground under the raster reaches above it."""
        finite = self.heights[np.isfinite(self.heights)]
        return float(finite.max()) if finite.size else -np.inf

    def height_at(self, xy_city: np.ndarray) -> F64:
        """Ground z at (N, 2) city points; NaN where unknown or out of bounds."""
        xy = np.asarray(xy_city, dtype=np.float64).reshape(-1, 2)
        p = self.s * (xy @ self.R.T + self.t)
        col = np.floor(p[:, 0]).astype(np.int64)
        row = np.floor(p[:, 1]).astype(np.int64)
        h, w = self.heights.shape
        ok = (col >= 0) & (col < w) & (row >= 0) & (row < h)
        out = np.full(len(xy), np.nan)
        out[ok] = self.heights[row[ok], col[ok]].astype(np.float64)
        return out


@dataclass
class SceneLog:
    """Everything downstream needs from one source log.

    ``rig`` is the source rig with this log's own calibration, in the source ego frame
    (whose origin is ``rig.origin_height_m`` above the ground).
    """

    log_id: str
    source: str  # "av2" or "synthetic"
    city: str  # e.g. "PIT"
    city_frame: str  # e.g. "PIT_city_57819"
    rig: Rig
    pose_timestamps_ns: np.ndarray  # (P,) int64, strictly increasing
    city_T_ego: F64  # (P, 4, 4)
    lidar_sweeps: list[LidarSweepRef]
    camera_frames: dict[str, list[CameraFrame]]
    annotations: Annotations
    vector_map: VectorMap | None
    ground_height: GroundHeightRaster | None = None
    split: str = ""  # source split name (train/val/test) where known
    load_lidar: Callable[[LidarSweepRef], LidarPoints] | None = field(default=None, repr=False)
    # Pose interpolation tolerance beyond the ends of the pose table.
    max_pose_extrapolation_ns: int = 0

    def city_T_ego_at(self, timestamp_ns) -> F64:
        """Ego pose(s) at arbitrary timestamps (slerp + lerp); (4,4) read-only for a scalar, else (M,4,4)."""
        key = (self.pose_timestamps_ns, self.city_T_ego, self.max_pose_extrapolation_ns)
        cached = self.__dict__.get("_pose_table")
        same = (cached is not None and cached[0][0] is key[0] and cached[0][1] is key[1]
                and cached[0][2] == key[2])
        if not same:  # built once (checked, quaternions precomputed); rebuilt if the table is replaced
            cached = (key, PoseTable(*key))
            self.__dict__["_pose_table"] = cached
        if np.ndim(timestamp_ns) == 0:
            return cached[1].at(int(timestamp_ns))
        return cached[1](timestamp_ns)

    def sweep(self, ref: LidarSweepRef) -> LidarPoints:
        if self.load_lidar is None:
            raise RuntimeError(f"log {self.log_id}: no lidar loader attached")
        return self.load_lidar(ref)

    @property
    def sweep_timestamps_ns(self) -> np.ndarray:
        return np.array([s.timestamp_ns for s in self.lidar_sweeps], dtype=np.int64)
