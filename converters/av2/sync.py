"""Which LiDAR sweeps have an image from every camera close enough in time to become a sample.

Cameras run at 20 Hz with fixed phase offsets to the 10 Hz LiDAR (up to ~24 ms), so a sweep
is kept only when each camera's nearest image lies within the tolerance (AV2's official 25 ms).
Sweeps that fail are skipped with a log line, never paired with a stale image.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from nuav2.scene import CameraFrame, LidarSweepRef, SceneLog

log = logging.getLogger(__name__)

DEFAULT_CAMERA_TOLERANCE_NS = 25_000_000
NO_IMAGE = np.iinfo(np.int64).max


@dataclass(frozen=True)
class SyncedSweep:
    """A sweep and, per camera, the image nearest to it in time."""

    sweep: LidarSweepRef
    frames: dict[str, CameraFrame]

    def max_offset_ns(self) -> int:
        return max((abs(f.timestamp_ns - self.sweep.timestamp_ns) for f in self.frames.values()), default=0)


def nearest_frame_indices(frame_ts_ns: np.ndarray, query_ns: np.ndarray) -> np.ndarray:
    """Index of the nearest frame to each query (ties go to the earlier frame); frames sorted by time."""
    frame_ts_ns = np.asarray(frame_ts_ns, dtype=np.int64)
    query_ns = np.asarray(query_ns, dtype=np.int64)
    hi = np.clip(np.searchsorted(frame_ts_ns, query_ns, side="left"), 0, len(frame_ts_ns) - 1)
    lo = np.clip(hi - 1, 0, len(frame_ts_ns) - 1)
    pick_lo = np.abs(query_ns - frame_ts_ns[lo]) <= np.abs(frame_ts_ns[hi] - query_ns)
    return np.where(pick_lo, lo, hi)


def synced_sweeps(scene: SceneLog, tolerance_ns: int = DEFAULT_CAMERA_TOLERANCE_NS,
                  channels: list[str] | None = None) -> list[SyncedSweep]:
    """Sweeps whose every camera (``channels``, default all rig cameras) has an image within tolerance.

    A camera with no images makes every sweep unsynced. A scene read without cameras
    (``channels`` empty) keeps every sweep with no frames.
    """
    channels = scene.rig.camera_channels if channels is None else list(channels)
    sweeps = scene.lidar_sweeps
    sweep_ts = scene.sweep_timestamps_ns
    ok = np.ones(len(sweeps), bool)
    picks: dict[str, np.ndarray] = {}
    off_ns: dict[str, np.ndarray] = {}
    for ch in channels:
        frames = scene.camera_frames.get(ch, [])
        if not frames:
            ok[:] = False
            off_ns[ch] = np.full(len(sweeps), NO_IMAGE)
            continue
        ts = np.array([f.timestamp_ns for f in frames], dtype=np.int64)
        idx = nearest_frame_indices(ts, sweep_ts)
        off = np.abs(ts[idx] - sweep_ts)
        picks[ch] = idx
        off_ns[ch] = off
        ok &= off <= tolerance_ns
    out, skipped = [], []
    for i, sweep in enumerate(sweeps):
        if not ok[i]:
            late = [f"{ch} ({off_ns[ch][i] / 1e6:.1f} ms)" if off_ns[ch][i] < NO_IMAGE else f"{ch} (none)"
                    for ch in channels if off_ns[ch][i] > tolerance_ns]
            skipped.append(f"sweep {sweep.timestamp_ns}: no image within {tolerance_ns / 1e6:.1f} ms from "
                           + ", ".join(late))
            log.info("log %s: skipped %s", scene.log_id, skipped[-1])
            continue
        out.append(SyncedSweep(sweep, {ch: scene.camera_frames[ch][int(picks[ch][i])] for ch in channels}))
    if skipped:
        log.warning("log %s: skipped %d of %d sweeps with a camera out of sync, first: %s", scene.log_id,
                    len(skipped), len(sweeps), skipped[0])
    return out
