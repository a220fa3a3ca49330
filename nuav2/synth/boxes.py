"""Oriented boxes (buildings, vehicles, pedestrians) and exact ray/box intersection.

Both the lidar and the camera renderer use :func:`intersect_rays`: a slab test in each box's
own frame, z-buffered across boxes, so overlapping or nested boxes always resolve to the
nearest surface (where a painter's sort by box distance can misorder). Rays need not be unit
length: ``t`` is in units of the given direction (the camera passes z = 1 rays, so its ``t``
is the camera z-depth).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from nuav2.geometry import F64

KIND_BUILDING, KIND_VEHICLE, KIND_PEDESTRIAN = 0, 1, 2
_TINY = 1e-12
# Unit cube corners (x, y, z in {-1, 1}) in a fixed order.
_CORNER_SIGNS = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], np.float64)


@dataclass(frozen=True, eq=False)
class BoxSet:
    """N boxes in the local frame: centre, yaw about +z, size (length along x, width, height)."""

    center: F64  # (N, 3)
    yaw: F64  # (N,)
    size: F64  # (N, 3)
    color: np.ndarray  # (N, 3) float32 RGB
    kind: np.ndarray  # (N,) int8
    reflectivity: np.ndarray  # (N,) uint8 lidar reflectivity

    def __len__(self) -> int:
        return len(self.yaw)

    @property
    def rotations(self) -> F64:
        """(N, 3, 3) local_R_box."""
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        R = np.zeros((len(self), 3, 3))
        R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = c, -s, s, c, 1.0
        return R

    def corners(self) -> F64:
        """(N, 8, 3) corners in the local frame."""
        half = self.size[:, None, :] / 2 * _CORNER_SIGNS[None]
        return np.einsum("nij,nkj->nki", self.rotations, half) + self.center[:, None, :]

    def subset(self, idx: np.ndarray) -> BoxSet:
        return BoxSet(self.center[idx], self.yaw[idx], self.size[idx], self.color[idx], self.kind[idx],
                      self.reflectivity[idx])

    @staticmethod
    def concat(*sets: BoxSet) -> BoxSet:
        return BoxSet(*(np.concatenate([getattr(s, f) for s in sets]) for f in
                        ("center", "yaw", "size", "color", "kind", "reflectivity")))

    @staticmethod
    def empty() -> BoxSet:
        return BoxSet(np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3), np.float32),
                      np.zeros(0, np.int8), np.zeros(0, np.uint8))


@dataclass(frozen=True)
class RayHits:
    """Nearest box hit per ray: ``box`` is -1 (and ``t`` inf) where no box is hit."""

    t: F64  # (M,)
    box: np.ndarray  # (M,) int64
    face: np.ndarray  # (M,) int8: 2 * axis + (1 if the +axis face else 0)


@numba.njit(cache=True, inline="always")
def _axis(o, d, h, t_in, t_out, ax_in, ax_out, a):
    """Clip the ray's [t_in, t_out] interval by slab |x_a| <= h; a miss returns t_in > t_out."""
    if abs(d) < _TINY:
        if o < -h or o > h:
            return np.inf, -np.inf, ax_in, ax_out
        return t_in, t_out, ax_in, ax_out
    inv = 1.0 / d
    t1 = (-h - o) * inv
    t2 = (h - o) * inv
    if t1 > t2:
        t1, t2 = t2, t1
    if t1 > t_in:
        t_in, ax_in = t1, a
    if t2 < t_out:
        t_out, ax_out = t2, a
    return t_in, t_out, ax_in, ax_out


@numba.njit(cache=True, inline="always")
def _slab(ox, oy, oz, dx, dy, dz, hx, hy, hz, t_min):
    """Nearest hit (t, face) of one ray with an axis-aligned box centred at 0; (inf, -1) if none."""
    t_in, t_out, ax_in, ax_out = _axis(ox, dx, hx, -np.inf, np.inf, 0, 0, 0)
    t_in, t_out, ax_in, ax_out = _axis(oy, dy, hy, t_in, t_out, ax_in, ax_out, 1)
    t_in, t_out, ax_in, ax_out = _axis(oz, dz, hz, t_in, t_out, ax_in, ax_out, 2)
    if t_in > t_out:
        return np.inf, -1
    if t_in > t_min:  # entering from outside: the face against the direction
        d = dx if ax_in == 0 else (dy if ax_in == 1 else dz)
        return t_in, 2 * ax_in + (1 if d < 0 else 0)
    if t_out > t_min:  # starting inside: the face the ray leaves through
        d = dx if ax_out == 0 else (dy if ax_out == 1 else dz)
        return t_out, 2 * ax_out + (1 if d > 0 else 0)
    return np.inf, -1


@numba.njit(cache=True, inline="always")
def _test_ray(j, i, ox, oy, oz, R, dirs, halves, t_min, t_max, t_best, box_best, face_best):
    dx, dy, dz = dirs[j, 0], dirs[j, 1], dirs[j, 2]
    bx = R[0, 0] * dx + R[1, 0] * dy + R[2, 0] * dz
    by = R[0, 1] * dx + R[1, 1] * dy + R[2, 1] * dz
    bz = R[0, 2] * dx + R[1, 2] * dy + R[2, 2] * dz
    t, face = _slab(ox, oy, oz, bx, by, bz, halves[i, 0], halves[i, 1], halves[i, 2], t_min)
    if face >= 0 and t < t_best[j] and t <= t_max:
        t_best[j] = t
        box_best[j] = i
        face_best[j] = face


@numba.njit(cache=True)
def _cast_kernel(origin, dirs, centers, rots, halves, order, t_lower, cos_half, rects, width, t_min, t_max,
                 t_best, box_best, face_best):
    """z-buffered slab tests, boxes nearest first (``order``). Box i is tested on the image rectangle
    rects[i] (r0, r1, c0, c1) when ``width`` > 0, else on the rays inside its bounding cone
    (cos_half[i] <= -1: every ray); a ray that already hit nearer than t_lower[i] skips box i."""
    for i in order:
        R = rots[i]
        rx, ry, rz = origin[0] - centers[i, 0], origin[1] - centers[i, 1], origin[2] - centers[i, 2]
        ox = R[0, 0] * rx + R[1, 0] * ry + R[2, 0] * rz
        oy = R[0, 1] * rx + R[1, 1] * ry + R[2, 1] * rz
        oz = R[0, 2] * rx + R[1, 2] * ry + R[2, 2] * rz
        lower = t_lower[i]
        if width > 0:
            for r in range(rects[i, 0], rects[i, 1] + 1):
                for c in range(rects[i, 2], rects[i, 3] + 1):
                    j = r * width + c
                    if t_best[j] > lower:
                        _test_ray(j, i, ox, oy, oz, R, dirs, halves, t_min, t_max,
                                  t_best, box_best, face_best)
        else:
            vx, vy, vz = -rx, -ry, -rz
            vn = np.sqrt(vx * vx + vy * vy + vz * vz)
            ch = cos_half[i]
            for j in range(dirs.shape[0]):
                if t_best[j] <= lower:
                    continue
                if ch > -1.0:
                    dx, dy, dz = dirs[j, 0], dirs[j, 1], dirs[j, 2]
                    dn = np.sqrt(dx * dx + dy * dy + dz * dz)
                    if dx * vx + dy * vy + dz * vz < (ch - 1e-9) * dn * vn:
                        continue
                _test_ray(j, i, ox, oy, oz, R, dirs, halves, t_min, t_max, t_best, box_best, face_best)


def intersect_rays(origin: F64, dirs: F64, boxes: BoxSet, *, t_min: float = 0.0, t_max: float = np.inf,
                   rects: np.ndarray | None = None, image_width: int = 0,
                   t_lower: np.ndarray | None = None) -> RayHits:
    """Nearest hit in (t_min, t_max] of rays ``origin + t * dirs`` with any box.

    Culling: with ``rects`` (N, 4) int (r0, r1, c0, c1; empty when r1 < r0) the rays are an image
    of ``image_width`` columns (row-major) and box i is tested only inside its rectangle; without,
    each box is tested on the rays inside the cone around its bounding sphere. ``t_lower`` (N,)
    are lower bounds of t on each box (default: for unit rays, centre distance minus radius);
    boxes are tested nearest-bound first and skip rays already hit nearer. A ray starting
    inside a box hits its inside (the exit face), so a camera inside a building sees walls.
    """
    origin = np.ascontiguousarray(origin, np.float64)
    dirs = np.ascontiguousarray(dirs, np.float64)
    m = len(dirs)
    t_best = np.full(m, np.inf)
    box_best = np.full(m, -1, np.int64)
    face_best = np.full(m, -1, np.int8)
    n = len(boxes)
    if n == 0 or m == 0:
        return RayHits(t_best, box_best, face_best)
    halves = np.ascontiguousarray(boxes.size / 2)
    dist = np.linalg.norm(boxes.center - origin, axis=1)
    radius = np.linalg.norm(halves, axis=1) * (1 + 1e-6) + 1e-6
    with np.errstate(invalid="ignore"):
        sin_half = radius / np.maximum(dist, 1e-300)
        cos_half = np.where(dist > radius, np.sqrt(np.clip(1.0 - sin_half**2, 0, 1)), -2.0)
    if t_lower is None:
        scale = float(np.max(np.linalg.norm(dirs, axis=1)))  # |d| <= scale: t >= distance / scale
        t_lower = np.maximum(dist - radius, 0.0) / max(scale, 1e-300)
    t_lower = np.ascontiguousarray(t_lower, np.float64)
    order = np.argsort(t_lower, kind="stable").astype(np.int64)
    if rects is None:
        rects_arr, width = np.zeros((n, 4), np.int64), 0
    else:
        rects_arr, width = np.ascontiguousarray(rects, np.int64), int(image_width)
        if rects_arr.shape != (n, 4) or width <= 0 or (rects_arr[:, 1].max() + 1) * width > m:
            raise ValueError("rects must be (N, 4) within an image of image_width columns")
    _cast_kernel(origin, dirs, np.ascontiguousarray(boxes.center), np.ascontiguousarray(boxes.rotations),
                 halves, order, t_lower, cos_half, rects_arr, width, float(t_min), float(t_max),
                 t_best, box_best, face_best)
    return RayHits(t_best, box_best, face_best)


def face_normals_local(boxes: BoxSet, box: np.ndarray, face: np.ndarray) -> F64:
    """(M, 3) outward normals in the local frame of the given (box, face) pairs."""
    n_b = np.zeros((len(box), 3))
    n_b[np.arange(len(box)), face // 2] = np.where(face % 2 == 1, 1.0, -1.0)
    return np.einsum("mij,mj->mi", boxes.rotations[box], n_b)

