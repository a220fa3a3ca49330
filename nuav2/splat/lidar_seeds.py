"""LiDAR seeds: sweeps aggregated in the scene frame (moving actors routed to their box frames),
voxel-downsampled more coarsely far from the ego path; box-surface filler; 3DGS kNN scales."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from nuav2.cells import cell_indices, cell_means, unique_cells
from nuav2.geometry import F64, T_inverse
from nuav2.progress import progress_bar
from nuav2.scene import SceneLog
from nuav2.splat.scene_model import TrackPoses

if TYPE_CHECKING:
    from nuav2.splat.init import InitConfig


def points_in_box(points: F64, box_T_frame: F64, size_lwh: F64, margin: float) -> np.ndarray:
    """Mask of (N,3) points (in some frame) inside a box given the frame->box transform."""
    p = points @ box_T_frame[:3, :3].T + box_T_frame[:3, 3]
    half = np.asarray(size_lwh) / 2 + margin
    return np.all(np.abs(p) <= half, axis=1)


@dataclass
class LidarAggregate:
    """Aggregated LiDAR: background in the scene frame, moving objects in their box frames."""

    background: F64  # (N, 3)
    objects: dict[str, F64]  # track id -> (M, 3)
    n_sweeps: int = 0
    n_points: int = 0


def aggregate_lidar(scene: SceneLog, scene_T_city: F64, moving: dict[str, TrackPoses], cfg: InitConfig,
                    *, progress: bool = False) -> LidarAggregate:
    """Move sweeps into the scene frame, routing points in moving boxes to their tracks."""
    ann = scene.annotations
    bg_parts: list[F64] = []
    obj_parts: dict[str, list[F64]] = {key: [] for key in moving}
    by_id: dict[str, list[TrackPoses]] = {}
    for track in moving.values():
        by_id.setdefault(track.track_id, []).append(track)
    sweeps = scene.lidar_sweeps[:: max(1, cfg.sweep_stride)]
    lo, hi = np.asarray(cfg.ego_box_min), np.asarray(cfg.ego_box_max)
    n_points = 0
    for ref in progress_bar(sweeps, desc=f"lidar {scene.log_id[:8]}", unit="sweep", disable=not progress,
                            leave=False):
        pts = scene.sweep(ref).xyz_ego
        pts = pts[np.all(np.isfinite(pts), axis=1)]
        pts = pts[~np.all((pts >= lo) & (pts <= hi), axis=1)]
        pts = pts[np.linalg.norm(pts, axis=1) <= cfg.max_range_m]
        n_points += len(pts)
        in_any = np.zeros(len(pts), bool)
        scene_T_ego = scene_T_city @ scene.city_T_ego_at(int(ref.timestamp_ns))
        for row in ann.at(int(ref.timestamp_ns)):
            for track in by_id.get(str(ann.track_id[row]), ()):
                if not track.present(int(ref.timestamp_ns)):
                    continue  # another segment of a non-rigid actor
                # the track's (smoothed) pose, not the raw label: its points must not carry the jitter
                box_T_ego = T_inverse(track.scene_T_box_at(int(ref.timestamp_ns))) @ scene_T_ego
                inside = points_in_box(pts, box_T_ego, track.size_lwh, cfg.box_margin_m) & ~in_any
                if np.any(inside):  # a point in two overlapping boxes goes to the first only
                    obj_parts[track.key].append(pts[inside] @ box_T_ego[:3, :3].T + box_T_ego[:3, 3])
                in_any |= inside
        rest = pts[~in_any]
        bg_parts.append(rest @ scene_T_ego[:3, :3].T + scene_T_ego[:3, 3])
    bg = np.concatenate(bg_parts) if bg_parts else np.zeros((0, 3))
    objs = {tid: (np.concatenate(p) if p else np.zeros((0, 3))) for tid, p in obj_parts.items()}
    return LidarAggregate(bg, objs, len(sweeps), n_points)


def voxel_downsample(points: F64, voxel_m: float) -> F64:
    """Centroid of the points in each occupied voxel (order: sorted voxel keys, deterministic)."""
    if len(points) == 0:
        return np.zeros((0, 3))
    if not voxel_m > 0:
        raise ValueError(f"voxel size must be > 0, got {voxel_m}")
    _, inv, counts = unique_cells(points, voxel_m)
    return cell_means(points, inv, counts)


def distance_to_path(points_xy: F64, path_xy: F64) -> F64:
    """Horizontal distance of each point to the nearest ego position."""
    from scipy.spatial import cKDTree

    d, _ = cKDTree(path_xy).query(points_xy, k=1)
    return np.asarray(d, np.float64)


def distance_bands(points_xy: F64, path_xy: F64, edges_m: tuple[float, ...],
                   cell_m: float = 1.0) -> np.ndarray:
    """Band of each point's distance to the path: k where ``edges[k-1] <= d < edges[k]`` (0 below the first
    edge), exactly as from :func:`distance_to_path`. The distance is asked once per ``cell_m`` cell (a 15 s
    log aggregates millions of LiDAR points, a kd-tree query each took 5 s); a point's distance is within
    half a cell diagonal of its cell centre's, so only the points of cells that straddle an edge are asked
    for their own."""
    points_xy = np.asarray(points_xy, np.float64).reshape(-1, 2)
    edges = np.asarray(edges_m, np.float64)
    if len(points_xy) == 0:
        return np.zeros(0, np.int64)
    first, inverse, _ = unique_cells(points_xy, cell_m)
    centre = (cell_indices(points_xy[first], cell_m) + 0.5) * cell_m
    d_cell = distance_to_path(centre, path_xy)
    reach = cell_m * np.sqrt(0.5) * (1 + 1e-9) + 1e-9
    lo = np.searchsorted(edges, d_cell - reach, side="right")
    band = lo[inverse]
    unsure = (lo != np.searchsorted(edges, d_cell + reach, side="right"))[inverse]
    if unsure.any():
        band[unsure] = np.searchsorted(edges, distance_to_path(points_xy[unsure], path_xy), side="right")
    return band


def banded_downsample(points: F64, path_xy: F64, voxel_m: float, bands_m: tuple[float, ...]) -> F64:
    """Voxel size doubles per distance band from the ego path (far scenery needs fewer seeds)."""
    if len(points) == 0:
        return points
    band = distance_bands(points[:, :2], path_xy, bands_m)
    parts = [voxel_downsample(points[band == k], voxel_m * 2**k) for k in range(len(bands_m) + 1)]
    return np.concatenate(parts)


def cap_points(points: F64, cap: int, rng: np.random.Generator) -> F64:
    if len(points) <= cap:
        return points
    return points[np.sort(rng.choice(len(points), cap, replace=False))]


def box_surface_points(size_lwh: F64, n: int, rng: np.random.Generator) -> F64:
    """n random points on a box's surface (faces picked by area), box frame."""
    l, w, h = (float(x) for x in size_lwh)
    areas = np.array([w * h, w * h, l * h, l * h, l * w, l * w])
    face = rng.choice(6, n, p=areas / areas.sum())
    u = rng.uniform(-0.5, 0.5, (n, 3)) * np.array([l, w, h])
    axis, sign = face // 2, np.where(face % 2 == 0, -0.5, 0.5)
    u[np.arange(n), axis] = sign * np.array([l, w, h])[axis]
    return u


def knn_scales(points: F64, k: int = 3, lo: float = 0.02, hi: float = 2.0) -> F64:
    """sqrt(mean squared distance to the k nearest neighbours), clamped: the 3DGS isotropic init."""
    if len(points) == 0:
        return np.zeros(0)
    if len(points) <= k:
        return np.full(len(points), lo)
    from scipy.spatial import cKDTree

    d, _ = cKDTree(points).query(points, k=k + 1)
    return np.clip(np.sqrt(np.mean(d[:, 1:] ** 2, axis=1)), lo, hi)
