"""Box layers that match the LiDAR: each track's box faces moved to where the actor's own points are.

Labels are a few centimetres off per track and a few per cent off in size. A box layer that misses
a strip of a car leaves that strip on the ground behind it (torn in the warp); one that covers a
strip of road moves the road with the car. Each track's points (those within ``margin_m`` of its
box at each sweep, in the box frame, all sweeps together, ground returns left out) say where the
actor really is: a side face with at least ``min_points`` points within ``margin_m`` of it (either
side) moves to the ``pct``-th percentile of the points along its axis, plus ``pad_m``, by at most
``max_move_m``; the top face likewise; the bottom stays on the ground. A face without such evidence
(a parked car's far side) stays where the label put it.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from nuav2.geometry import T_inverse, quat_to_rot
from nuav2.scene import SceneLog
from nuav2.warp.tracks import BoxTracks

MARGIN_M = 0.3
MAX_MOVE_M = 0.25
PAD_M = 0.03
MIN_POINTS = 20
PCT = 2.0
GROUND_CLEAR_M = 0.15  # points this close to the box bottom are ground (or tyre contact), not sides


def gather_track_points(tracks: BoxTracks, scene: SceneLog, margin_m: float = MARGIN_M,
                        sweep_stride: int = 1) -> list[list[np.ndarray]]:
    """Per track, the box-frame LiDAR points within ``margin_m`` of its box, one array per sweep."""
    out: list[list[np.ndarray]] = [[] for _ in range(len(tracks))]
    if scene.load_lidar is None or len(tracks) == 0:
        return out
    for ref in scene.lidar_sweeps[::max(1, sweep_stride)]:
        t = int(ref.timestamp_ns)
        boxes = tracks.at(t)
        if len(boxes) == 0:
            continue
        xyz = np.asarray(scene.sweep(ref).xyz_ego, np.float64)
        xyz = xyz[np.all(np.isfinite(xyz), axis=1)]
        city_T_ego = scene.city_T_ego_at(t)
        for k, city_T_box, size in zip(boxes.track, boxes.city_T_box, boxes.size_lwh):
            box_T_ego = T_inverse(city_T_box) @ city_T_ego
            centre_ego = T_inverse(box_T_ego)[:3, 3]
            reach = np.linalg.norm(size / 2 + margin_m)
            near = np.all(np.abs(xyz - centre_ego) <= reach, axis=1)
            if not near.any():
                continue
            p = xyz[near] @ box_T_ego[:3, :3].T + box_T_ego[:3, 3]
            inside = np.all(np.abs(p) <= size / 2 + margin_m, axis=1)
            if inside.any():
                out[int(k)].append(p[inside])
    return out


def face_moves(points: np.ndarray, size_lwh: np.ndarray, margin_m: float = MARGIN_M,
               max_move_m: float = MAX_MOVE_M, pad_m: float = PAD_M, min_points: int = MIN_POINTS,
               pct: float = PCT) -> tuple[np.ndarray, np.ndarray]:
    """(low, high) face coordinates (3,) in the box frame after the refit (the label: -size/2, +size/2)."""
    half = np.asarray(size_lwh, np.float64) / 2
    lo, hi = -half.copy(), half.copy()
    if len(points) == 0:
        return lo, hi
    side = points[points[:, 2] > -half[2] + GROUND_CLEAR_M]
    for a in range(3):
        p = side[:, a] if a < 2 else side[:, 2]
        if len(p) < min_points:
            continue
        if a < 2 and np.sum(np.abs(p + half[a]) <= margin_m) >= min_points:
            lo[a] = np.clip(np.percentile(p, pct) - pad_m, -half[a] - max_move_m, -half[a] + max_move_m)
        if np.sum(np.abs(p - half[a]) <= margin_m) >= min_points:
            hi[a] = np.clip(np.percentile(p, 100 - pct) + pad_m, half[a] - max_move_m, half[a] + max_move_m)
    return lo, hi


def refit_boxes(tracks: BoxTracks, points: list[list[np.ndarray]], **kw) -> tuple[BoxTracks, np.ndarray]:
    """``tracks`` with every track's box moved and resized to its LiDAR ``points`` (box frame, from
    :func:`gather_track_points`; see module doc), and each track's (3,) box-frame shift."""
    t_box, size = tracks.city_t_box.copy(), tracks.size_lwh.copy()
    shifts = np.zeros((len(tracks), 3))
    for k in range(len(tracks)):
        s, e = int(tracks.starts[k]), int(tracks.starts[k + 1])
        if not points[k]:
            continue
        med = np.median(tracks.size_lwh[s:e], axis=0)
        lo, hi = face_moves(np.concatenate(points[k]), med, **kw)
        shifts[k] = (lo + hi) / 2
        R = quat_to_rot(tracks.city_q_box[s:e])
        t_box[s:e] += np.einsum("nij,j->ni", R, shifts[k])
        size[s:e] = hi - lo
    return replace(tracks, city_t_box=t_box, size_lwh=size), shifts


def actor_models(points: list[list[np.ndarray]], shifts: np.ndarray,
                 voxel_m: float = 0.05) -> list[np.ndarray]:
    """Per track, its points of all sweeps in its (refit) box frame, one per ``voxel_m`` voxel: the shape the
    box layer is checked against (``ProxyGeometry.actor_points_city``)."""
    out = []
    for k, parts in enumerate(points):
        if not parts:
            out.append(np.zeros((0, 3)))
            continue
        p = np.concatenate(parts) - shifts[k]
        _, first = np.unique(np.floor(p / voxel_m).astype(np.int64), axis=0, return_index=True)
        out.append(p[np.sort(first)])
    return out
