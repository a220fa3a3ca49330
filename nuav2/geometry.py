"""Rigid-body geometry in float64: quaternions (w, x, y, z), 4x4 SE3 matrices, pose interpolation.

Poses compose as ``a_T_c = a_T_b @ b_T_c`` ("a from c"); a 4x4 matrix maps homogeneous
points of its right frame into its left frame. Everything here stays float64 because AV2
city coordinates reach several km, where float32 loses millimetres.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

F64 = NDArray[np.float64]

QUAT_EPS = 1e-12


def quat_normalize(q_wxyz: ArrayLike) -> F64:
    """Unit quaternion(s) with w >= 0; raises on a zero or non-finite quaternion."""
    q = np.asarray(q_wxyz, dtype=np.float64)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    if not np.all(np.isfinite(q)) or np.any(n < QUAT_EPS):
        raise ValueError(f"quaternion must be finite and non-zero, got {q.tolist()}")
    q = q / n
    return np.where(q[..., :1] < 0, -q, q)


def quat_to_rot(q_wxyz: ArrayLike) -> F64:
    """Rotation matrix (..., 3, 3) from (..., 4) quaternions (normalised first)."""
    w, x, y, z = np.moveaxis(quat_normalize(q_wxyz), -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def rot_to_quat(R: ArrayLike) -> F64:
    """Quaternion (w >= 0) from rotation matrices (..., 3, 3), vectorised.

    Uses Shepperd's method: per matrix, the largest of (trace, R00, R11, R22) picks the
    branch whose square root is well away from zero, so precision holds near 180 degrees.
    """
    R = np.asarray(R, dtype=np.float64)
    batch = R.shape[:-2]
    m = R.reshape(-1, 3, 3)
    m00, m01, m02 = m[:, 0, 0], m[:, 0, 1], m[:, 0, 2]
    m10, m11, m12 = m[:, 1, 0], m[:, 1, 1], m[:, 1, 2]
    m20, m21, m22 = m[:, 2, 0], m[:, 2, 1], m[:, 2, 2]
    tr = m00 + m11 + m22
    choice = np.argmax(np.stack([tr, m00, m11, m22], -1), -1)
    cands = np.empty((4, len(m), 4))
    s = 2.0 * np.sqrt(np.maximum(1.0 + tr, 1e-300))
    cands[0] = np.stack([0.25 * s, (m21 - m12) / s, (m02 - m20) / s, (m10 - m01) / s], -1)
    s = 2.0 * np.sqrt(np.maximum(1.0 + m00 - m11 - m22, 1e-300))
    cands[1] = np.stack([(m21 - m12) / s, 0.25 * s, (m01 + m10) / s, (m02 + m20) / s], -1)
    s = 2.0 * np.sqrt(np.maximum(1.0 + m11 - m00 - m22, 1e-300))
    cands[2] = np.stack([(m02 - m20) / s, (m01 + m10) / s, 0.25 * s, (m12 + m21) / s], -1)
    s = 2.0 * np.sqrt(np.maximum(1.0 + m22 - m00 - m11, 1e-300))
    cands[3] = np.stack([(m10 - m01) / s, (m02 + m20) / s, (m12 + m21) / s, 0.25 * s], -1)
    q = cands[choice, np.arange(len(m))]
    return quat_normalize(q).reshape(*batch, 4)


def quat_multiply(a_wxyz: ArrayLike, b_wxyz: ArrayLike) -> F64:
    """Hamilton product a * b (rotation b first, then a)."""
    a = np.asarray(a_wxyz, dtype=np.float64)
    b = np.asarray(b_wxyz, dtype=np.float64)
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        -1,
    )


def quat_slerp(q0_wxyz: ArrayLike, q1_wxyz: ArrayLike, t: ArrayLike) -> F64:
    """Shortest-path spherical interpolation; falls back to normalised lerp for tiny angles."""
    q0 = quat_normalize(q0_wxyz)
    q1 = quat_normalize(q1_wxyz)
    t = np.asarray(t, dtype=np.float64)[..., None]
    dot = np.sum(q0 * q1, -1, keepdims=True)
    q1 = np.where(dot < 0, -q1, q1)
    dot = np.abs(dot)
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    sin_theta = np.sin(theta)
    small = sin_theta < 1e-9
    safe = np.where(small, 1.0, sin_theta)
    w0 = np.where(small, 1.0 - t, np.sin((1.0 - t) * theta) / safe)
    w1 = np.where(small, t, np.sin(t * theta) / safe)
    return quat_normalize(w0 * q0 + w1 * q1)


def make_T(R: ArrayLike, t: ArrayLike) -> F64:
    """4x4 (or batched) homogeneous transform from rotation(s) and translation(s)."""
    R = np.asarray(R, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    T = np.zeros(R.shape[:-2] + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def T_from_quat_trans(q_wxyz: ArrayLike, t: ArrayLike) -> F64:
    """Transform from a (w, x, y, z) quaternion and a translation (batched)."""
    return make_T(quat_to_rot(q_wxyz), t)


def T_to_quat_trans(T: ArrayLike) -> tuple[F64, F64]:
    """(quaternion wxyz, translation) of transform(s)."""
    T = np.asarray(T, dtype=np.float64)
    return rot_to_quat(T[..., :3, :3]), T[..., :3, 3].copy()


def T_inverse(T: ArrayLike) -> F64:
    """Exact rigid inverse (R^T, -R^T t), batched."""
    T = np.asarray(T, dtype=np.float64)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    t = T[..., :3, 3]
    return make_T(Rt, -np.einsum("...ij,...j->...i", Rt, t))


def transform_points(a_T_b: ArrayLike, points_b: ArrayLike) -> F64:
    """Map (N, 3) points from frame b into frame a."""
    a_T_b = np.asarray(a_T_b, dtype=np.float64)
    p = np.asarray(points_b, dtype=np.float64)
    return p @ a_T_b[:3, :3].T + a_T_b[:3, 3]


def translation_T(x: float = 0.0, y: float = 0.0, z: float = 0.0) -> F64:
    """Pure translation transform."""
    T = np.eye(4)
    T[:3, 3] = (x, y, z)
    return T


def yaw_of(R: ArrayLike) -> float:
    """Heading (rad, counter-clockwise about +z) of the rotated x-axis."""
    R = np.asarray(R, dtype=np.float64)
    return float(np.arctan2(R[1, 0], R[0, 0]))


def interpolate_poses(
    timestamps_ns: ArrayLike,
    poses: ArrayLike,
    query_ns: ArrayLike,
    max_extrapolation_ns: int = 0,
) -> F64:
    """Poses at arbitrary timestamps: slerp on rotation, lerp on translation (see :class:`PoseTable`)."""
    return PoseTable(timestamps_ns, poses, max_extrapolation_ns)(query_ns)


class PoseTable:
    """A checked pose table that interpolates: slerp on rotation, lerp on translation.

    ``timestamps_ns`` must be sorted and strictly increasing (duplicates are removed by the
    caller). Queries outside the table by up to ``max_extrapolation_ns`` clamp to the end
    pose; further out is an error, because silently holding a pose would shift geometry.
    Interpolation weights are computed from int64 differences so ns precision is kept. The
    table is checked and turned into quaternions once (a log's poses are queried thousands of times).
    """

    def __init__(self, timestamps_ns: ArrayLike, poses: ArrayLike, max_extrapolation_ns: int = 0):
        ts = np.asarray(timestamps_ns, dtype=np.int64)
        poses = np.asarray(poses, dtype=np.float64)
        if ts.ndim != 1 or len(ts) == 0 or poses.shape != (len(ts), 4, 4):
            raise ValueError("interpolate_poses needs N timestamps and (N, 4, 4) poses")
        if len(ts) > 1 and np.any(np.diff(ts) <= 0):
            raise ValueError("pose timestamps must be strictly increasing")
        if not np.all(np.isfinite(poses)):
            raise ValueError("pose table contains NaN/Inf")
        self.timestamps_ns = ts
        self.max_extrapolation_ns = int(max_extrapolation_ns)
        self._quats, self._trans = T_to_quat_trans(poses)
        self._memo: dict[int, F64] = {}

    def at(self, query_ns: int) -> F64:
        """(4, 4) pose at one timestamp, memoised (a log's sweep and image times are asked for again and
        again); read-only, so a caller cannot change the memo."""
        t = int(query_ns)
        pose = self._memo.get(t)
        if pose is None:
            if len(self._memo) >= 16384:
                self._memo.clear()
            pose = self(t)[0]
            pose.flags.writeable = False
            self._memo[t] = pose
        return pose

    def prefetch(self, query_ns: ArrayLike) -> None:
        """Memoise the poses at many timestamps in one vectorised call (the same values :meth:`at` gives;
        one call per time costs ~1 ms of numpy overhead, and seeding asks for every image's time)."""
        q = np.unique(np.asarray(query_ns, dtype=np.int64).ravel())
        q = q[[int(t) not in self._memo for t in q]]
        if len(q) == 0:
            return
        if len(self._memo) + len(q) > 16384:
            self._memo.clear()
        for t, pose in zip(q, self(q)):
            pose.flags.writeable = False
            self._memo[int(t)] = pose

    def __call__(self, query_ns: ArrayLike) -> F64:
        """(M, 4, 4) poses at the M query timestamps."""
        ts, ext = self.timestamps_ns, self.max_extrapolation_ns
        q = np.atleast_1d(np.asarray(query_ns, dtype=np.int64))
        lo_bad = q < ts[0] - ext
        hi_bad = q > ts[-1] + ext
        if np.any(lo_bad | hi_bad):
            bad = q[lo_bad | hi_bad][0]
            raise ValueError(
                f"timestamp {bad} ns is outside the pose table [{ts[0]}, {ts[-1]}] "
                f"by more than {ext} ns"
            )
        qc = np.clip(q, ts[0], ts[-1])
        hi = np.clip(np.searchsorted(ts, qc, side="left"), 0, len(ts) - 1)
        lo = np.clip(hi - 1, 0, len(ts) - 1)
        exact = ts[hi] == qc
        lo = np.where(exact, hi, lo)
        span = (ts[hi] - ts[lo]).astype(np.float64)
        alpha = np.where(span > 0, (qc - ts[lo]).astype(np.float64) / np.where(span > 0, span, 1.0), 0.0)
        q_out = quat_slerp(self._quats[lo], self._quats[hi], alpha)
        t_lo, t_hi = self._trans[lo], self._trans[hi]
        t_out = t_lo + alpha[:, None] * (t_hi - t_lo)
        return T_from_quat_trans(q_out, t_out)


def egoS_T_egoT_from_heights(source_origin_height_m: float, target_origin_height_m: float) -> F64:
    """Frame alignment (paper eq. 1): both vehicle frames sit on the rear axle, x forward,
    z up; they differ only in how high the origin is above the ground. A point at height h
    above ground has z = h - origin_height in each frame."""
    return translation_T(z=target_origin_height_m - source_origin_height_m)
