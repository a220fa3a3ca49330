"""Ego motion from a chain of poses: what nuScenes' CAN bus pose message holds (acceleration, rotation
rate, velocity in the ego frame), for AV2 logs that have no CAN bus. Shared by the CAN bus expansion
the converter writes and the ``can_bus`` of ``nuav2 infos``, so the two always agree."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from nuav2.geometry import F64, rot_to_quat

GRAVITY_MPS2 = 9.81  # what a level accelerometer at rest reads on +z (nuScenes' CAN pose accel does)


def rotation_vector(R: F64) -> F64:
    """Log map of a rotation matrix (axis * angle, rad): closed form from the skew part, which is
    exact and cheap for the small rotations between sweeps; the quaternion route past 90 degrees."""
    s = 0.5 * np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])  # sin(angle) * axis
    c = 0.5 * (R[0, 0] + R[1, 1] + R[2, 2] - 1.0)  # cos(angle)
    sin_angle = float(np.linalg.norm(s))
    if c > 0.0:
        return s * (math.atan2(sin_angle, c) / sin_angle) if sin_angle > 1e-15 else s
    q = rot_to_quat(R)  # w >= 0
    v = q[1:]
    return v * (2.0 * math.atan2(float(np.linalg.norm(v)), float(q[0])) / float(np.linalg.norm(v)))


def ego_motion(times_s: Sequence[float], global_T_ego: Sequence[F64] | F64, index: int) -> F64:
    """[acceleration (3), rotation rate (3), velocity (3)] of pose ``index`` in its ego frame, the
    fields nuScenes' CAN pose message holds (m/s^2, rad/s, m/s), by finite differences of poses at
    strictly increasing ``times_s``: central where both neighbours exist, one-sided at the ends
    (the acceleration from the three end poses). The acceleration is what an accelerometer reads
    (specific force, gravity included: [0, 0, 9.81] level at rest), so the values look like the CAN
    bus MapTR's nuScenes converter stores. With a single pose, rate and velocity are zero and the
    acceleration is gravity's reading alone (so too the acceleration with two poses)."""
    n = len(times_s)
    t = np.asarray(times_s, dtype=np.float64)
    global_T = np.asarray(global_T_ego, dtype=np.float64)
    ego_R_global = global_T[index, :3, :3].T
    motion = np.zeros(9)
    lo, hi = max(index - 1, 0), min(index + 1, n - 1)
    if hi > lo:
        dt = t[hi] - t[lo]
        lo_R_hi = global_T[lo, :3, :3].T @ global_T[hi, :3, :3]
        # The rotation vector is in the ego frame at ``lo``; moved into the frame at ``index``.
        motion[3:6] = ego_R_global @ global_T[lo, :3, :3] @ (rotation_vector(lo_R_hi) / dt)
        motion[6:9] = ego_R_global @ ((global_T[hi, :3, 3] - global_T[lo, :3, 3]) / dt)
    accel_global = np.array([0.0, 0.0, GRAVITY_MPS2])
    if n >= 3:
        i = min(max(index - 1, 0), n - 3)  # first of the three poses nearest to ``index``
        (t0, t1, t2), (p0, p1, p2) = t[i : i + 3], global_T[i : i + 3, :3, 3]
        accel_global += 2.0 / (t2 - t0) * ((p2 - p1) / (t2 - t1) - (p1 - p0) / (t1 - t0))
    motion[0:3] = ego_R_global @ accel_global
    return motion
