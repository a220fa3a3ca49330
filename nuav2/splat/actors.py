"""Annotated tracks as the reconstruction sees them: box poses in the scene frame, which move, which bend.

A moving rigid actor (a car) is one object in its box frame for the whole log. A moving
*non-rigid* actor (a walking pedestrian, a cyclist: :data:`nuav2.actor_tracks.NON_RIGID`) changes
shape inside its box, and one rigid Gaussian set for the whole log would average its limbs into a smear; it is
modelled instead as consecutive short time segments (:func:`segment_track`), each its own object
seeded and trained only from the sweeps and images of its segment (a per-frame fallback).
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from nuav2.actor_tracks import is_non_rigid, smooth_box_poses
from nuav2.geometry import F64, T_from_quat_trans
from nuav2.scene import SceneLog
from nuav2.splat.scene_model import TrackPoses

if TYPE_CHECKING:
    from nuav2.splat.init import InitConfig

def segment_track(track: TrackPoses, segment_ns: int) -> list[TrackPoses]:
    """A track cut into consecutive time segments of ``segment_ns`` (the last one takes the rest), each
    present only in its own half-open window, together covering the track's presence."""
    start = int(track.timestamps_ns[0]) - track.presence_margin_ns
    end = int(track.timestamps_ns[-1]) + track.presence_margin_ns + 1
    n = max(1, int((end - start) // max(1, int(segment_ns))))
    edges = [start + k * int(segment_ns) for k in range(n)] + [end]
    return [replace(track, segment=k, present_from_ns=a, present_until_ns=b, pose_delta=None)
            for k, (a, b) in enumerate(zip(edges[:-1], edges[1:]))]


def object_tracks(tracks: list[TrackPoses], cfg: InitConfig) -> list[TrackPoses]:
    """The objects to model: every moving track, non-rigid ones cut into ``cfg.nonrigid_segment_s`` segments
    (0: kept whole, as rigid)."""
    out = []
    for t in tracks:
        if not is_moving(t, cfg):
            continue
        if cfg.nonrigid_segment_s > 0 and is_non_rigid(t.category):
            out += segment_track(t, int(cfg.nonrigid_segment_s * 1e9))
        else:
            out.append(t)
    return out


def build_tracks(scene: SceneLog, scene_T_city: F64, smooth: bool = False) -> list[TrackPoses]:
    """Every annotated track's box poses in the scene frame, sorted by track id; ``smooth`` takes per-frame
    label jitter out (:mod:`nuav2.actor_tracks`)."""
    ann = scene.annotations
    tracks = []
    for tid in sorted(set(ann.track_id.tolist())):
        rows = np.flatnonzero(ann.track_id == tid)
        rows = rows[np.argsort(ann.timestamp_ns[rows], kind="stable")]
        ts = ann.timestamp_ns[rows].astype(np.int64)
        keep = np.concatenate([[True], np.diff(ts) > 0])  # a repeated timestamp keeps its first box
        rows, ts = rows[keep], ts[keep]
        ego_T_box = T_from_quat_trans(ann.ego_q_box[rows], ann.ego_t_box[rows])
        scene_T_box = scene_T_city[None] @ scene.city_T_ego_at(ts).reshape(-1, 4, 4) @ ego_T_box
        if smooth:
            scene_T_box = smooth_box_poses(ts, scene_T_box)
        tracks.append(TrackPoses(str(tid), str(ann.category[rows[0]]), np.median(ann.size_lwh[rows], axis=0),
                                 ts, scene_T_box))
    return tracks


def track_motion(track: TrackPoses) -> tuple[float, float]:
    """(path length, largest per-axis std) of the box centre, metres."""
    c = track.scene_T_box[:, :3, 3]
    path = float(np.linalg.norm(np.diff(c, axis=0), axis=1).sum()) if len(c) > 1 else 0.0
    return path, float(c.std(axis=0).max())


def is_moving(track: TrackPoses, cfg: InitConfig) -> bool:
    """Model a track as its own object only if it really moves: path AND spread above thresholds
    (path alone grows with annotation jitter on long static tracks)."""
    if len(track.timestamps_ns) < cfg.motion_min_observations:
        return False
    path, std = track_motion(track)
    return path > cfg.motion_min_path_m and std > cfg.motion_min_std_m
