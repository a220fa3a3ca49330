"""Cuboid annotations of a sweep, exact or as imperfect as human labels are.

Without the ``label_noise`` factor each actor's cuboid is its exact pose and size at the sweep
time. With it: every track keeps a fixed offset (centimetres along its axes, a fraction of a
degree of yaw) and a few per cent of size error, every frame adds jitter, and far or heavily
occluded objects (few lidar points) are sometimes left unlabelled, as in real logs.

The jitter (``FRAME_JITTER_M``, ``FRAME_YAW_DEG``: its standard deviation in any one frame) is smooth
in time, as real labels are (tracked, then smoothed): per track and axis a sum of ``JITTER_WAVES``
sinusoids of random frequency (``JITTER_HZ``, a correlation time of about 1 s) and Gaussian
amplitudes, a function of the timestamp drawn from the seed and the track. White jitter of the same
size would move a parked car's box 4 cm in 0.1 s, a finite-difference speed of ~0.5 m/s (the devkit's
'moving' threshold) and accelerations of metres per second squared; this one reads ~0.04 m/s and
~0.05 m/s^2 there, like real logs.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass

import numpy as np

from nuav2.geometry import F64, make_T

TRACK_OFFSET_M = (0.06, 0.06, 0.03)
TRACK_YAW_DEG = 0.4
SIZE_ERROR = 0.03
FRAME_JITTER_M = (0.03, 0.03, 0.015)
FRAME_YAW_DEG = 0.25
JITTER_HZ = (0.05, 0.3)  # frequencies of the jitter's sinusoids
JITTER_WAVES = 4  # sinusoids per track and axis
FAR_M = 50.0
FEW_POINTS = 5


@dataclass(frozen=True)
class LabelNoiseParts:
    """Which parts of the label noise apply (all by default); the others are drawn and discarded, so a part
    keeps the same errors whichever others are on (``docs/ablation/label_noise_parts.py`` costs each)."""

    track_offset: bool = True  # per-track constant pose offset and yaw
    size: bool = True  # per-track size error
    frame_jitter: bool = True  # pose and yaw jitter (per frame, smooth in time)
    missed: bool = True  # far or hidden objects left unlabelled


ALL_PARTS = LabelNoiseParts()


def _rz(a: F64) -> F64:
    c, s = np.cos(a), np.sin(a)
    R = np.zeros((len(a), 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = c, -s, s, c, 1.0
    return R


def frame_jitter(seed: int, track_uuids: list[str], timestamp_ns: int) -> tuple[F64, F64]:
    """(K, 3) offsets along the box axes (m) and (K,) yaws (rad) of the jitter at ``timestamp_ns``: a
    smooth function of time per track, N(0, FRAME_JITTER_M / FRAME_YAW_DEG) in any one frame."""
    k = len(track_uuids)
    freq, coef = np.zeros((k, 4, JITTER_WAVES)), np.zeros((k, 2, 4, JITTER_WAVES))
    for i, uid in enumerate(track_uuids):
        rng = np.random.default_rng([seed, 302, zlib.crc32(uid.encode())])
        freq[i] = rng.uniform(*JITTER_HZ, (4, JITTER_WAVES))
        coef[i] = rng.normal(0.0, 1.0 / np.sqrt(JITTER_WAVES), (2, 4, JITTER_WAVES))
    # Cycles since the epoch (~5e8: float64 keeps 1e-7 of a cycle), reduced mod 1 before the cosine.
    phase = 2.0 * np.pi * np.mod(freq * (int(timestamp_ns) * 1e-9), 1.0)
    wave = (coef[:, 0] * np.cos(phase) + coef[:, 1] * np.sin(phase)).sum(axis=-1)  # (K, 4), unit std
    sigma = np.array([*FRAME_JITTER_M, np.deg2rad(FRAME_YAW_DEG)])
    jitter = wave * sigma
    return jitter[:, :3], jitter[:, 3]


def label_errors(
    seed: int, track_uuids: list[str], timestamp_ns: int, ego_T_box: F64, size: F64, num_points: np.ndarray,
    parts: LabelNoiseParts = ALL_PARTS,
) -> tuple[F64, F64, np.ndarray]:
    """(ego_T_label (K, 4, 4), label sizes (K, 3), kept (K,) bool) for one sweep's true cuboids."""
    k = len(track_uuids)
    track_off = np.zeros((k, 3))
    track_yaw = np.zeros(k)
    scale = np.ones((k, 3))
    for i, uid in enumerate(track_uuids):
        rng = np.random.default_rng([seed, 300, zlib.crc32(uid.encode())])
        track_off[i] = rng.normal(0.0, TRACK_OFFSET_M)
        track_yaw[i] = np.deg2rad(rng.normal(0.0, TRACK_YAW_DEG))
        scale[i] = 1.0 + rng.normal(0.0, SIZE_ERROR, 3)
    rng = np.random.default_rng([seed, 301, int(timestamp_ns) % (1 << 62)])
    rng.standard_normal(4 * k)  # what white per-frame jitter drew: the misses below keep their draws
    jitter, jitter_yaw = frame_jitter(seed, track_uuids, timestamp_ns)
    off = track_off * parts.track_offset + jitter * parts.frame_jitter
    yaw = track_yaw * parts.track_offset + jitter_yaw * parts.frame_jitter
    box_T_label = make_T(_rz(yaw), off)
    dist = np.linalg.norm(ego_T_box[:, :2, 3], axis=1)
    p_miss = np.where(num_points == 0, 0.7, np.where(num_points < FEW_POINTS, 0.4, 0.0))
    p_miss = np.maximum(p_miss, np.where(dist > FAR_M, 0.35, 0.0))
    kept = (rng.uniform(size=k) >= p_miss) | (not parts.missed)
    scale = np.clip(scale, 0.9, 1.1) if parts.size else np.ones_like(scale)
    return ego_T_box @ box_T_label, size * scale, kept
