"""A log's timeline: which sweeps become samples, which images are key frames, and µs timestamps.

nuScenes links every sensor reading to a sample: key frames to their own sample, the others
("sweeps") to the sample that follows them. Samples are LiDAR sweeps picked at a configurable
rate (default: every sweep, 10 Hz in AV2, as the MapGS paper does). A camera's key frame for a
sample is its image nearest to the sweep within 25 ms (AV2's own tolerance); its other images
become sweeps. AV2 timestamps are ns and collide when truncated to µs, so µs labels are made
unique across the whole log by a deterministic bump (see :func:`unique_microseconds`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

log = logging.getLogger(__name__)

KEY_IMAGE_TOLERANCE_NS = 25_000_000


def _check_increasing(ns: np.ndarray, what: str) -> np.ndarray:
    ns = np.asarray(ns, dtype=np.int64)
    if ns.ndim != 1:
        raise ValueError(f"{what}: timestamps must be a 1-D array")
    if len(ns) > 1 and np.any(np.diff(ns) <= 0):
        i = int(np.flatnonzero(np.diff(ns) <= 0)[0])
        raise ValueError(f"{what}: timestamps must be strictly increasing "
                         f"(index {i}: {ns[i]} then {ns[i + 1]})")
    return ns


def select_keyframes(sweep_ns: np.ndarray, keyframe_hz: float | None) -> np.ndarray:
    """Indices of the sweeps that become samples.

    ``None`` keeps every sweep. Otherwise sweeps are kept greedily from the first one whenever
    at least ``1/keyframe_hz`` minus half a sweep interval has passed since the last kept one,
    so 10 Hz sweeps at ``keyframe_hz=2`` keep every 5th sweep even with jittery clocks.
    """
    ns = _check_increasing(sweep_ns, "lidar sweeps")
    if keyframe_hz is None or len(ns) < 2:
        return np.arange(len(ns))
    if not (np.isfinite(keyframe_hz) and keyframe_hz > 0):
        raise ValueError(f"keyframe rate must be a positive number of Hz, got {keyframe_hz}")
    period_ns = 1e9 / keyframe_hz
    sweep_period_ns = float(np.median(np.diff(ns)))
    if period_ns < 0.75 * sweep_period_ns:  # asked for more samples than there are sweeps
        log.warning("--keyframe-hz %g is above the sweep rate (%.3g Hz): every sweep is a sample",
                    keyframe_hz, 1e9 / sweep_period_ns)
    min_gap_ns = period_ns - 0.5 * sweep_period_ns
    keep = [0]
    for i in range(1, len(ns)):
        if ns[i] - ns[keep[-1]] >= min_gap_ns:
            keep.append(i)
    return np.asarray(keep, dtype=np.int64)


def match_key_images(key_ns: np.ndarray, image_ns: np.ndarray,
                     tolerance_ns: int = KEY_IMAGE_TOLERANCE_NS) -> np.ndarray:
    """For each key time, the index of the nearest image within ``tolerance_ns``, or -1.

    An image serves at most one key time (the nearer; the earlier on a tie).
    """
    key_ns = np.asarray(key_ns, dtype=np.int64)
    img = _check_increasing(image_ns, "camera images")
    out = np.full(len(key_ns), -1, dtype=np.int64)
    if len(img) == 0:
        return out
    hi = np.clip(np.searchsorted(img, key_ns), 0, len(img) - 1)
    lo = np.clip(hi - 1, 0, len(img) - 1)
    d_lo = np.abs(img[lo] - key_ns)
    d_hi = np.abs(img[hi] - key_ns)
    best = np.where(d_lo <= d_hi, lo, hi)
    dist = np.minimum(d_lo, d_hi)
    claimed: dict[int, int] = {}
    for k in np.argsort(dist, kind="stable"):
        if dist[k] > tolerance_ns:
            continue
        j = int(best[k])
        if j not in claimed:
            claimed[j] = int(k)
            out[k] = j
    return out


def owning_samples(ts_ns: np.ndarray, key_ns: np.ndarray) -> np.ndarray:
    """Sample index of non-key readings: the first sample at or after them, else the last one."""
    if len(key_ns) == 0:
        raise ValueError("a log needs at least one sample")
    idx = np.searchsorted(np.asarray(key_ns, dtype=np.int64), np.asarray(ts_ns, dtype=np.int64), side="left")
    return np.minimum(idx, len(key_ns) - 1)


def unique_microseconds(ns: np.ndarray, priority: np.ndarray) -> np.ndarray:
    """Integer µs labels, strictly increasing in (ns, priority) order.

    Each label is ``ns // 1000``, bumped to one µs after the previous label where that would
    collide; the bump is at most the number of readings sharing a µs, a few µs in AV2.
    """
    ns = np.asarray(ns, dtype=np.int64)
    order = np.lexsort((np.asarray(priority), ns))
    us_sorted = ns[order] // 1000
    for i in range(1, len(us_sorted)):
        if us_sorted[i] <= us_sorted[i - 1]:
            us_sorted[i] = us_sorted[i - 1] + 1
    out = np.empty_like(us_sorted)
    out[order] = us_sorted
    return out


@dataclass(frozen=True)
class TimelineFrame:
    """One reading to write: ``index`` points into its channel's input list."""

    channel: str
    index: int
    timestamp_ns: int
    timestamp_us: int
    is_key_frame: bool
    sample_index: int


@dataclass(frozen=True)
class Timeline:
    key_ns: np.ndarray  # (S,) sample (= key sweep) times, ns
    key_us: np.ndarray  # (S,) sample timestamps, µs (the key LiDAR frame's)
    frames: dict[str, list[TimelineFrame]]  # per channel, in time order

    @property
    def num_samples(self) -> int:
        return len(self.key_ns)


def plan_samples(sweep_ns: np.ndarray, camera_ns: dict[str, np.ndarray], keyframe_hz: float | None,
                 tolerance_ns: int = KEY_IMAGE_TOLERANCE_NS) -> np.ndarray:
    """Indices of the sweeps that become samples.

    Only sweeps where every camera has an image within ``tolerance_ns`` can be samples (a
    sample without one of its cameras breaks camera-based loaders); among them the keyframe
    rate picks. With no cameras every sweep is a candidate.
    """
    sweeps = _check_increasing(sweep_ns, "lidar sweeps")
    if len(sweeps) == 0:
        raise ValueError("the log has no LiDAR sweeps, so it has no samples")
    candidate = np.ones(len(sweeps), bool)
    for channel, ns in camera_ns.items():
        ns = _check_increasing(ns, f"camera {channel}")
        if len(ns) == 0:
            candidate[:] = False
            break
        hi = np.clip(np.searchsorted(ns, sweeps), 0, len(ns) - 1)
        lo = np.clip(hi - 1, 0, len(ns) - 1)
        dist = np.minimum(np.abs(ns[lo] - sweeps), np.abs(ns[hi] - sweeps))
        candidate &= dist <= tolerance_ns
    cand_idx = np.flatnonzero(candidate)
    if len(cand_idx) == 0:
        raise ValueError(f"no LiDAR sweep has an image from every camera ({sorted(camera_ns)}) "
                         f"within {tolerance_ns / 1e6:g} ms, so the log has no samples")
    return cand_idx[select_keyframes(sweeps[cand_idx], keyframe_hz)]


def build_timeline(lidar_channel: str, sweep_ns: np.ndarray, key_idx: np.ndarray,
                   camera_ns: dict[str, np.ndarray], tolerance_ns: int = KEY_IMAGE_TOLERANCE_NS) -> Timeline:
    """Every reading's sample, key-frame flag and µs label (unique across all channels of the log)."""
    sweeps = _check_increasing(sweep_ns, f"{lidar_channel} sweeps")
    key_idx = np.asarray(key_idx, dtype=np.int64)
    if len(key_idx) == 0:
        raise ValueError("a log needs at least one sample")
    key_ns = sweeps[key_idx]
    _check_increasing(key_ns, "samples")

    # (channel, index, ns, is_key, sample) for every reading; the channel order is the µs tie-break.
    rows: list[tuple[str, int, int, bool, int]] = []
    sweep_owner = owning_samples(sweeps, key_ns)
    sweep_owner[key_idx] = np.arange(len(key_idx))
    is_key_sweep = np.zeros(len(sweeps), bool)
    is_key_sweep[key_idx] = True
    rows += [(lidar_channel, i, int(sweeps[i]), bool(is_key_sweep[i]), int(sweep_owner[i]))
             for i in range(len(sweeps))]
    for channel, ns in camera_ns.items():
        ns = _check_increasing(ns, f"camera {channel}")
        key_image = match_key_images(key_ns, ns, tolerance_ns)
        owner = owning_samples(ns, key_ns)
        is_key = np.zeros(len(ns), bool)
        for s, j in enumerate(key_image):
            if j >= 0:
                owner[j] = s
                is_key[j] = True
        rows += [(channel, i, int(ns[i]), bool(is_key[i]), int(owner[i])) for i in range(len(ns))]

    channels = [lidar_channel, *camera_ns]
    priority = np.array([channels.index(r[0]) for r in rows])
    us = unique_microseconds(np.array([r[2] for r in rows], dtype=np.int64), priority)
    frames: dict[str, list[TimelineFrame]] = {ch: [] for ch in channels}
    for (ch, i, t, key, s), u in zip(rows, us):
        frames[ch].append(TimelineFrame(ch, i, t, int(u), key, s))
    key_us = np.array([f.timestamp_us for f in frames[lidar_channel] if f.is_key_frame], dtype=np.int64)
    return Timeline(key_ns=key_ns, key_us=key_us, frames=frames)
