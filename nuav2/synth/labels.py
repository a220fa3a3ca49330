"""Cuboid annotations of a sweep, exact or as imperfect as human labels are.

Without the ``label_noise`` factor each actor's cuboid is its exact pose and size at the sweep
time. With it: every track keeps a fixed offset (centimetres along its axes, a fraction of a
degree of yaw) and a few per cent of size error, every frame adds its own jitter, and far or
heavily occluded objects (few lidar points) are sometimes left unlabelled, as in real logs.
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
FAR_M = 50.0
FEW_POINTS = 5


@dataclass(frozen=True)
class LabelNoiseParts:
    """Which parts of the label noise apply (all by default); the others are drawn and discarded, so a part
    keeps the same errors whichever others are on (``docs/ablation/label_noise_parts.py`` costs each)."""

    track_offset: bool = True  # per-track constant pose offset and yaw
    size: bool = True  # per-track size error
    frame_jitter: bool = True  # per-frame pose and yaw jitter
    missed: bool = True  # far or hidden objects left unlabelled


ALL_PARTS = LabelNoiseParts()


def _rz(a: F64) -> F64:
    c, s = np.cos(a), np.sin(a)
    R = np.zeros((len(a), 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = c, -s, s, c, 1.0
    return R


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
    jitter = rng.normal(0.0, FRAME_JITTER_M, (k, 3))
    jitter_yaw = np.deg2rad(rng.normal(0.0, FRAME_YAW_DEG, k))
    off = track_off * parts.track_offset + jitter * parts.frame_jitter
    yaw = track_yaw * parts.track_offset + jitter_yaw * parts.frame_jitter
    box_T_label = make_T(_rz(yaw), off)
    dist = np.linalg.norm(ego_T_box[:, :2, 3], axis=1)
    p_miss = np.where(num_points == 0, 0.7, np.where(num_points < FEW_POINTS, 0.4, 0.0))
    p_miss = np.maximum(p_miss, np.where(dist > FAR_M, 0.35, 0.0))
    kept = (rng.uniform(size=k) >= p_miss) | (not parts.missed)
    scale = np.clip(scale, 0.9, 1.1) if parts.size else np.ones_like(scale)
    return ego_T_box @ box_T_label, size * scale, kept
