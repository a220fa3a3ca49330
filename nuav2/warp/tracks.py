"""Annotated cuboid tracks as city-frame poses that can be asked for at any time.

AV2 boxes are annotated at sweep times in the ego frame; the warp needs each actor's pose at
the target time and at every source image's own time (up to ~25 ms off a sweep), so boxes are
moved into the city frame once and interpolated per track (slerp + lerp), extrapolated
linearly for a short ``tolerance_ns`` past a track's ends.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from nuav2.actor_tracks import STATIC_STD_M, is_static, smooth_box_poses
from nuav2.geometry import F64, T_from_quat_trans, T_to_quat_trans, quat_slerp
from nuav2.scene import SceneLog

DEFAULT_TOLERANCE_NS = 60_000_000


@dataclass(frozen=True)
class BoxesAt:
    """Boxes present at one time: their track number, city pose and size."""

    track: np.ndarray  # (B,) int64 index into BoxTracks.track_ids
    city_T_box: F64  # (B, 4, 4)
    size_lwh: F64  # (B, 3)

    def __len__(self) -> int:
        return len(self.track)


@dataclass(frozen=True)
class BoxTracks:
    """All tracks of a log, rows sorted by (track, time); ``starts[k]:starts[k+1]`` is track k."""

    track_ids: np.ndarray  # (T,) object
    starts: np.ndarray  # (T + 1,) int64
    timestamp_ns: np.ndarray  # (K,) int64
    city_q_box: F64  # (K, 4)
    city_t_box: F64  # (K, 3)
    size_lwh: F64  # (K, 3)
    category: np.ndarray = field(default_factory=lambda: np.zeros(0, object))  # (T,) per track

    @staticmethod
    def from_scene(scene: SceneLog, smooth: bool = False) -> BoxTracks:
        """All tracks of ``scene`` in the city frame; ``smooth`` takes per-frame label jitter out
        (:mod:`nuav2.actor_tracks`) and gives each track its median size."""
        ann = scene.annotations
        lo = scene.pose_timestamps_ns[0] - scene.max_pose_extrapolation_ns
        hi = scene.pose_timestamps_ns[-1] + scene.max_pose_extrapolation_ns
        covered = (ann.timestamp_ns >= lo) & (ann.timestamp_ns <= hi)  # rows the poses can place in the city
        if not np.any(covered):
            return BoxTracks(np.zeros(0, object), np.zeros(1, np.int64), np.zeros(0, np.int64),
                             np.zeros((0, 4)), np.zeros((0, 3)), np.zeros((0, 3)))
        rows = np.flatnonzero(covered)
        track_ids, track_of = np.unique(ann.track_id[rows].astype(str), return_inverse=True)
        order = rows[np.lexsort((ann.timestamp_ns[rows], track_of))]
        track_of_row = np.empty(len(ann), np.int64)
        track_of_row[rows] = track_of
        ts = ann.timestamp_ns[order].astype(np.int64)
        trk = track_of_row[order]
        # Drop repeated (track, time) rows: interpolation needs strictly increasing times per track.
        keep = np.ones(len(ts), bool)
        keep[1:] = (trk[1:] != trk[:-1]) | (ts[1:] != ts[:-1])
        order, ts, trk = order[keep], ts[keep], trk[keep]
        city_T_ego = scene.city_T_ego_at(ts).reshape(-1, 4, 4)
        ego_T_box = T_from_quat_trans(ann.ego_q_box[order], ann.ego_t_box[order])
        city_T_box = city_T_ego @ ego_T_box
        size = np.asarray(ann.size_lwh, np.float64)[order]
        starts = np.searchsorted(trk, np.arange(len(track_ids) + 1)).astype(np.int64)
        if smooth:
            for a, b in zip(starts[:-1], starts[1:]):
                city_T_box[a:b] = smooth_box_poses(ts[a:b], city_T_box[a:b])
                size[a:b] = np.median(size[a:b], axis=0)
        q, t = T_to_quat_trans(city_T_box)
        category = np.asarray(ann.category, object)[order][starts[:-1]]
        return BoxTracks(track_ids, starts, ts, q, t, size, category)

    def __len__(self) -> int:
        return len(self.track_ids)

    def moving(self, static_std_m: float = STATIC_STD_M) -> np.ndarray:
        """(T,) bool: which tracks move (centre spread above ``static_std_m``, as nuav2.actor_tracks)."""
        return np.array([not is_static(self.city_t_box[a:b], static_std_m)
                         for a, b in zip(self.starts[:-1], self.starts[1:])], bool)

    def select(self, keep: np.ndarray) -> BoxTracks:
        """The tracks where ``keep`` (T,) is True, in the same order."""
        keep = np.asarray(keep, bool)
        rows = np.concatenate([np.arange(self.starts[k], self.starts[k + 1]) for k in np.flatnonzero(keep)]
                              or [np.zeros(0, np.int64)]).astype(np.int64)
        counts = np.diff(self.starts)[keep]
        starts = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        category = self.category[keep] if len(self.category) == len(keep) else self.category
        return BoxTracks(self.track_ids[keep], starts, self.timestamp_ns[rows], self.city_q_box[rows],
                         self.city_t_box[rows], self.size_lwh[rows], category)

    def at(self, timestamp_ns: int, tolerance_ns: int = DEFAULT_TOLERANCE_NS) -> BoxesAt:
        """Every track alive at ``timestamp_ns`` (within ``tolerance_ns`` of its ends), posed at that time.
        Vectorised over tracks: the warp asks once per image, and a busy log has hundreds of tracks."""
        t = int(timestamp_ns)
        first, last = self.starts[:-1], self.starts[1:] - 1
        alive = np.flatnonzero((self.timestamp_ns[first] - tolerance_ns <= t)
                               & (t <= self.timestamp_ns[last] + tolerance_ns))
        if len(alive) == 0:
            return BoxesAt(np.zeros(0, np.int64), np.zeros((0, 4, 4)), np.zeros((0, 3)))
        s, n = self.starts[alive], (last - first + 1)[alive]
        at_or_before = np.add.reduceat((self.timestamp_ns <= t).astype(np.int64), self.starts[:-1])[alive]
        j = np.minimum(np.maximum(at_or_before, 1), np.maximum(n - 1, 1))  # segment [j - 1, j] of the track
        single = n == 1
        lo = np.where(single, s, s + j - 1)
        hi = np.where(single, s, s + j)
        span = np.where(single, 1.0, (self.timestamp_ns[hi] - self.timestamp_ns[lo]).astype(np.float64))
        alpha = np.where(single, 0.0, (t - self.timestamp_ns[lo]).astype(np.float64) / span)
        q = quat_slerp(self.city_q_box[lo], self.city_q_box[hi], alpha)
        tr = self.city_t_box[lo] + alpha[:, None] * (self.city_t_box[hi] - self.city_t_box[lo])
        near = np.where(alpha < 0.5, lo, hi)
        return BoxesAt(alive.astype(np.int64), T_from_quat_trans(q, tr), self.size_lwh[near])
