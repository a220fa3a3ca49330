"""Annotated actor tracks as both re-rendering modes need them: label jitter smoothed out, which actors bend.

Smoothing: per-frame label jitter is taken out before boxes are used.
Human (and auto-) labels place each frame's cuboid a few centimetres and a fraction of a degree
off, independently per frame. Rendering or warping with those poses shakes actors between
frames and tears them from their surroundings. A track that does not move (its centre spread
stays under ``static_std_m``) gets one pose: the median centre and the circular mean heading.
A moving track gets, at each annotated time, a local quadratic fit of centre and unwrapped
heading over the ``half_window`` neighbours on each side (exact for constant acceleration and
steady turning, so real motion is kept while independent jitter shrinks by about half). The
tilt (roll, pitch) of each frame is kept. A constant per-track offset cannot be seen from the
poses alone and is left alone.
"""

from __future__ import annotations

import numpy as np

from nuav2.geometry import F64

STATIC_STD_M = 0.3
HALF_WINDOW = 4

# AV2 categories whose shape changes inside their box (limbs, pedalling, riders): a rigid box model
# (render mode's objects, warp mode's box layers) only approximates them.
NON_RIGID = frozenset({"PEDESTRIAN", "BICYCLIST", "MOTORCYCLIST", "WHEELED_RIDER", "OFFICIAL_SIGNALER",
                       "WHEELCHAIR", "STROLLER", "DOG", "ANIMAL"})


def is_non_rigid(category: str) -> bool:
    return str(category).upper() in NON_RIGID


def _yaw(R: F64) -> F64:
    return np.arctan2(R[..., 1, 0], R[..., 0, 0])


def _rz(yaw: F64) -> F64:
    c, s = np.cos(yaw), np.sin(yaw)
    R = np.zeros((*np.shape(yaw), 3, 3))
    R[..., 0, 0], R[..., 0, 1], R[..., 1, 0], R[..., 1, 1], R[..., 2, 2] = c, -s, s, c, 1.0
    return R


def is_static(centres: F64, static_std_m: float = STATIC_STD_M) -> bool:
    return len(centres) < 2 or float(np.asarray(centres).std(axis=0).max()) <= static_std_m


def smooth_box_poses(timestamps_ns: np.ndarray, frame_T_box: F64, *, half_window: int = HALF_WINDOW,
                     static_std_m: float = STATIC_STD_M) -> F64:
    """(N, 4, 4) poses of one track (times strictly increasing) with the per-frame jitter smoothed out."""
    T = np.asarray(frame_T_box, np.float64).reshape(-1, 4, 4)
    n = len(T)
    if n < 3:
        return T.copy()
    centre, R = T[:, :3, 3], T[:, :3, :3]
    yaw = np.unwrap(_yaw(R))
    tilt = np.einsum("nji,njk->nik", _rz(yaw), R)  # Rz(yaw)^T R: what is left after the heading
    if is_static(centre, static_std_m):
        new_centre = np.repeat(np.median(centre, axis=0)[None], n, axis=0)
        new_yaw = np.full(n, np.arctan2(np.sin(yaw).mean(), np.cos(yaw).mean()))
    else:
        t = (np.asarray(timestamps_ns, np.int64) - int(timestamps_ns[0])) * 1e-9
        new_centre, new_yaw = np.empty_like(centre), np.empty_like(yaw)
        for i in range(n):
            lo, hi = max(0, i - half_window), min(n, i + half_window + 1)
            dt = t[lo:hi] - t[i]
            A = np.column_stack([np.ones_like(dt), dt, dt * dt]) if hi - lo >= 4 else \
                np.column_stack([np.ones_like(dt), dt])
            coef = np.linalg.lstsq(A, np.column_stack([centre[lo:hi], yaw[lo:hi]]), rcond=None)[0]
            new_centre[i], new_yaw[i] = coef[0, :3], coef[0, 3]
    out = T.copy()
    out[:, :3, :3] = _rz(new_yaw) @ tilt
    out[:, :3, 3] = new_centre
    return out
