"""Convex solids (boxes, optionally cut by an ellipsoid or elliptic cylinder) and exact ray hits.

Every solid is an oriented box; ``quad`` (inverse squared radii per box axis, 0 = unbounded)
optionally intersects it with the quadric sum(q_i x_i^2) <= 1 in the same frame, which gives
rounded car bodies, wheels and poles (cylinders), foliage and heads (ellipsoids) while keeping
one exact, convex ray test. Both the lidar and the camera renderer use :func:`intersect_rays`:
the box slab interval meets the quadric interval in each solid's own frame, z-buffered across
solids, so overlapping or nested solids always resolve to the nearest surface (where a painter's
sort can misorder). Rays need not be unit length: ``t`` is in units of the given direction (the
camera passes z = 1 rays, so its ``t`` is the camera z-depth).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from nuav2.geometry import F64

KIND_BUILDING, KIND_VEHICLE, KIND_PEDESTRIAN = 0, 1, 2  # the original box materials (see materials.py)
FACE_QUADRIC = 6  # RayHits.face of a hit on the quadric surface
_TINY = 1e-12
# Unit cube corners (x, y, z in {-1, 1}) in a fixed order.
_CORNER_SIGNS = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], np.float64)


_FIELDS = ("center", "yaw", "size", "color", "kind", "reflectivity", "rot", "quad", "owner", "params")


@dataclass(frozen=True, eq=False)
class BoxSet:
    """N solids in the local frame: centre, yaw about +z (or a full rotation ``rot``), size (length
    along x, width, height), material, and optionally a quadric cut and the actor that owns them."""

    center: F64  # (N, 3)
    yaw: F64  # (N,)
    size: F64  # (N, 3)
    color: np.ndarray  # (N, 3) float32 RGB
    kind: np.ndarray  # (N,) int8 material (materials.py)
    reflectivity: np.ndarray  # (N,) uint8 lidar reflectivity
    rot: F64 | None = None  # (N, 3, 3) local_R_box; None: from yaw
    quad: F64 | None = None  # (N, 3) inverse squared quadric radii (0: no bound on that axis); None: zeros
    owner: np.ndarray | None = None  # (N,) int64 actor index (-1: static); None: all static
    params: F64 | None = None  # (N, 4) material parameters; None: zeros

    def __post_init__(self) -> None:
        n = len(self.yaw)
        if self.rot is None:
            c, s = np.cos(self.yaw), np.sin(self.yaw)
            R = np.zeros((n, 3, 3))
            R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = c, -s, s, c, 1.0
            object.__setattr__(self, "rot", R)
        if self.quad is None:
            object.__setattr__(self, "quad", np.zeros((n, 3)))
        if self.owner is None:
            object.__setattr__(self, "owner", np.full(n, -1, np.int64))
        if self.params is None:
            object.__setattr__(self, "params", np.zeros((n, 4)))

    def __len__(self) -> int:
        return len(self.yaw)

    @property
    def rotations(self) -> F64:
        """(N, 3, 3) local_R_box."""
        return self.rot

    def corners(self) -> F64:
        """(N, 8, 3) corners in the local frame."""
        half = self.size[:, None, :] / 2 * _CORNER_SIGNS[None]
        return np.einsum("nij,nkj->nki", self.rotations, half) + self.center[:, None, :]

    def subset(self, idx: np.ndarray) -> BoxSet:
        return BoxSet(*(getattr(self, f)[idx] for f in _FIELDS))

    @staticmethod
    def concat(*sets: BoxSet) -> BoxSet:
        return BoxSet(*(np.concatenate([getattr(s, f) for s in sets]) for f in _FIELDS))

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
def solid_hit(ox, oy, oz, dx, dy, dz, hx, hy, hz, qx, qy, qz, t_min):
    """Nearest hit (t, face) of a ray (in the solid's frame) with box |x| <= h cut by the quadric
    qx x^2 + qy y^2 + qz z^2 <= 1 (all q = 0: the plain box); face FACE_QUADRIC on the quadric."""
    if qx == 0.0 and qy == 0.0 and qz == 0.0:
        return _slab(ox, oy, oz, dx, dy, dz, hx, hy, hz, t_min)
    t_in, t_out, ax_in, ax_out = _axis(ox, dx, hx, -np.inf, np.inf, 0, 0, 0)
    t_in, t_out, ax_in, ax_out = _axis(oy, dy, hy, t_in, t_out, ax_in, ax_out, 1)
    t_in, t_out, ax_in, ax_out = _axis(oz, dz, hz, t_in, t_out, ax_in, ax_out, 2)
    if t_in > t_out:
        return np.inf, -1
    a = qx * dx * dx + qy * dy * dy + qz * dz * dz
    b = 2.0 * (qx * ox * dx + qy * oy * dy + qz * oz * dz)
    c = qx * ox * ox + qy * oy * oy + qz * oz * oz - 1.0
    if a < _TINY:
        if c > 0.0:
            return np.inf, -1
    else:
        disc = b * b - 4.0 * a * c
        if disc < 0.0:
            return np.inf, -1
        sq = np.sqrt(disc)
        qq = -0.5 * (b + sq) if b >= 0.0 else -0.5 * (b - sq)
        r1 = qq / a
        r2 = c / qq if qq != 0.0 else r1
        if r1 > r2:
            r1, r2 = r2, r1
        if r1 > t_in:
            t_in, ax_in = r1, 3
        if r2 < t_out:
            t_out, ax_out = r2, 3
        if t_in > t_out:
            return np.inf, -1
    if t_in > t_min:
        if ax_in == 3:
            return t_in, FACE_QUADRIC
        d = dx if ax_in == 0 else (dy if ax_in == 1 else dz)
        return t_in, 2 * ax_in + (1 if d < 0 else 0)
    if t_out > t_min:
        if ax_out == 3:
            return t_out, FACE_QUADRIC
        d = dx if ax_out == 0 else (dy if ax_out == 1 else dz)
        return t_out, 2 * ax_out + (1 if d > 0 else 0)
    return np.inf, -1


@numba.njit(cache=True, inline="always")
def _test_ray(j, i, ox, oy, oz, R, dirs, halves, quads, t_min, t_max, t_best, box_best, face_best):
    dx, dy, dz = dirs[j, 0], dirs[j, 1], dirs[j, 2]
    bx = R[0, 0] * dx + R[1, 0] * dy + R[2, 0] * dz
    by = R[0, 1] * dx + R[1, 1] * dy + R[2, 1] * dz
    bz = R[0, 2] * dx + R[1, 2] * dy + R[2, 2] * dz
    t, face = solid_hit(ox, oy, oz, bx, by, bz, halves[i, 0], halves[i, 1], halves[i, 2], quads[i, 0],
                        quads[i, 1], quads[i, 2], t_min)
    if face >= 0 and t < t_best[j] and t <= t_max:
        t_best[j] = t
        box_best[j] = i
        face_best[j] = face


@numba.njit(cache=True)
def _cast_kernel(origin, dirs, centers, rots, halves, quads, order, t_lower, cos_half, rects, width, t_min,
                 t_max, t_best, box_best, face_best):
    """z-buffered solid tests, nearest first (``order``). Solid i is tested on the image rectangle
    rects[i] (r0, r1, c0, c1) when ``width`` > 0, else on the rays inside its bounding cone
    (cos_half[i] <= -1: every ray); a ray that already hit nearer than t_lower[i] skips solid i."""
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
                        _test_ray(j, i, ox, oy, oz, R, dirs, halves, quads, t_min, t_max,
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
                _test_ray(j, i, ox, oy, oz, R, dirs, halves, quads, t_min, t_max, t_best, box_best,
                          face_best)


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
                 halves, np.ascontiguousarray(boxes.quad, np.float64), order, t_lower, cos_half, rects_arr,
                 width, float(t_min), float(t_max), t_best, box_best, face_best)
    return RayHits(t_best, box_best, face_best)


def face_normals_local(boxes: BoxSet, box: np.ndarray, face: np.ndarray, points: F64 | None = None) -> F64:
    """(M, 3) outward normals in the local frame of the given (box, face) pairs; hits on a quadric
    (FACE_QUADRIC) need their local ``points``."""
    n_b = np.zeros((len(box), 3))
    flat = face != FACE_QUADRIC
    idx = np.flatnonzero(flat)
    n_b[idx, face[idx] // 2] = np.where(face[idx] % 2 == 1, 1.0, -1.0)
    quad = np.flatnonzero(~flat)
    if len(quad):
        if points is None:
            raise ValueError("hits on a quadric need their points for the normal")
        R = boxes.rotations[box[quad]]
        p_b = np.einsum("mji,mj->mi", R, points[quad] - boxes.center[box[quad]])
        g = boxes.quad[box[quad]] * p_b
        n_b[quad] = g / np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-12)
    return np.einsum("mij,mj->mi", boxes.rotations[box], n_b)

