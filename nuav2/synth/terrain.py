"""The ground surface z = h(x, y) of the local frame: smooth relief plus a kerb step.

``h = H(x, y) + KERB_H * ramp(SD(x, y))``: ``H`` is the relief (random long-wave grades up to
about 8 %, crests and sags, a 2 % cross-fall from each road's crown to its gutters), stored as a
bilinear raster that blends into a constant far out; ``SD`` is the signed distance to the
drivable-area boundary (negative on the road), so the sidewalk and everything beyond stands a
kerb height above the gutter, with a near-vertical face ``KERB_W`` wide at the boundary.

Rays meet the surface by conservative marching: ``z - H`` can shrink no faster than
``L |d_xy| - d_z`` (``L`` bounds |grad H|) and the kerb term changes only within ``KERB_W / 2``
of the boundary (``SD`` changes at most sqrt(2) per metre), so every step is safe and the first
intersection is never skipped; the last few centimetres are closed by Newton steps with a
bracket. A flat terrain keeps the plane formula ``t = -o_z / d_z`` exactly.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numba
import numpy as np
import shapely

from nuav2.geometry import F64

KERB_H = 0.15  # kerb height above the gutter (m)
KERB_W = 0.04  # width of the kerb face ramp (m)
RELIEF_RES_M = 0.5
KERB_RES_M = 0.25
TAPER_M = 40.0  # the relief blends to a constant over this band at the raster border
CROSS_FALL = 0.02
MAX_GRADE = 0.08
_SQRT2 = float(np.sqrt(2.0))
_F_NEWTON = 0.02  # below this height above the surface, Newton steps (bracketed) finish the search
_F_DONE = 1e-6
_MAX_STEPS = 600
# Packed scalars: relief grid x0, y0, res; kerb grid x0, y0, res; L; kerb height; kerb width; h min; h max;
# far height (outside both rasters); flat flag.
_M_HX0, _M_HY0, _M_HRES, _M_SX0, _M_SY0, _M_SRES, _M_L, _M_KH, _M_KW, _M_HMIN, _M_HMAX, _M_HFAR, _M_FLAT = (
    range(13)
)


@dataclass(frozen=True, eq=False)
class Terrain:
    """Ground surface: ``meta`` (13 scalars), relief raster ``H`` and kerb distance raster ``SD``."""

    meta: F64
    H: np.ndarray  # float64 (ny, nx), node (i, j) at (x0 + j res, y0 + i res)
    SD: np.ndarray  # float64 (my, mx)

    @property
    def flat(self) -> bool:
        return bool(self.meta[_M_FLAT])

    def arrays(self) -> tuple[F64, np.ndarray, np.ndarray]:
        return self.meta, self.H, self.SD

    def height(self, xy: F64) -> F64:
        """(N,) surface height at local (N, 2) points."""
        xy = np.ascontiguousarray(np.asarray(xy, np.float64).reshape(-1, 2))
        out = np.empty(len(xy))
        _heights(*self.arrays(), xy, out)
        return out

    def relief(self, xy: F64) -> F64:
        """(N,) height of the relief alone (the road surface, no kerb step)."""
        xy = np.ascontiguousarray(np.asarray(xy, np.float64).reshape(-1, 2))
        out = np.empty(len(xy))
        _reliefs(*self.arrays(), xy, out)
        return out

    def normal(self, xy: F64) -> F64:
        """(N, 3) unit upward surface normals."""
        xy = np.ascontiguousarray(np.asarray(xy, np.float64).reshape(-1, 2))
        out = np.empty((len(xy), 3))
        _normals(*self.arrays(), xy, out)
        return out

    def intersect(self, origin: F64, dirs: F64, t_min: float, t_max: float) -> F64:
        """(M,) ray parameter of the first surface hit in [t_min, t_max], inf where none."""
        out = np.empty(len(dirs))
        _intersect_many(
            *self.arrays(),
            np.ascontiguousarray(origin, np.float64),
            np.ascontiguousarray(dirs, np.float64),
            float(t_min),
            float(t_max),
            out,
        )
        return out


def flat_terrain() -> Terrain:
    meta = np.zeros(13)
    meta[_M_HRES] = meta[_M_SRES] = 1.0
    meta[_M_FLAT] = 1.0
    return Terrain(meta, np.zeros((2, 2)), np.full((2, 2), 1e9))


def _relief_field(rng: np.random.Generator, x: F64, y: F64) -> F64:
    """Sum of long-wave cosines (wavelengths 70-260 m): grades, crests and sags."""
    h = np.zeros(np.broadcast(x, y).shape)
    for _ in range(6):
        lam = rng.uniform(70.0, 260.0)
        ang = rng.uniform(0.0, np.pi)
        k = 2 * np.pi / lam
        h = h + rng.uniform(0.4, 1.0) * lam * np.cos(
            k * (np.cos(ang) * x + np.sin(ang) * y) + rng.uniform(0, 2 * np.pi)
        )
    return h


def build_terrain(
    rng: np.random.Generator,
    half_extent: float,
    drivable,
    axes: list[F64],
    crown_half_m: float,
    relief: bool,
    kerb: bool,
) -> Terrain:
    """Terrain over the square |x|, |y| <= ``half_extent`` (constant beyond).

    ``drivable``: shapely (Multi)Polygon of the road surface (kerbs at its boundary); ``axes``:
    road crown polylines for the cross-fall. h(0, 0) on the road is 0 (the local origin).
    """
    if not relief and not kerb:
        return flat_terrain()
    ext = float(np.ceil(half_extent))
    meta = np.zeros(13)
    # Relief raster.
    n = int(round(2 * ext / RELIEF_RES_M)) + 1
    g = -ext + np.arange(n) * RELIEF_RES_M
    if relief:
        X, Y = np.meshgrid(g, g)
        field = _relief_field(rng, X, Y)
        gy, gx = np.gradient(field, RELIEF_RES_M)
        grade = rng.uniform(0.75, 1.0) * MAX_GRADE
        field *= grade / max(float(np.max(np.hypot(gx, gy))), 1e-12)
        axis_mask = np.zeros((n, n), np.uint8)
        for ax in axes:
            px = np.round((np.asarray(ax) + ext) / RELIEF_RES_M * 16).astype(np.int32)
            cv2.polylines(axis_mask, [px], False, 1, 1, cv2.LINE_8, 4)
        d_axis = cv2.distanceTransform((1 - axis_mask).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
        H = field - CROSS_FALL * np.minimum(d_axis * RELIEF_RES_M, crown_half_m)
        # Blend to the mean far out, so the surface is constant beyond the raster.
        edge = (
            np.minimum.outer(
                np.minimum(np.arange(n), n - 1 - np.arange(n)), np.minimum(np.arange(n), n - 1 - np.arange(n))
            )
            * RELIEF_RES_M
        )
        w = np.clip(edge / TAPER_M, 0.0, 1.0)
        w = w * w * (3 - 2 * w)
        h_far = float(np.mean(H))
        H = h_far + w * (H - h_far)
        H -= _bilinear_np(H, -ext, RELIEF_RES_M, 0.0, 0.0)  # the local origin is on the ground
        d = np.abs(np.diff(H, axis=1))
        e = np.abs(np.diff(H, axis=0))
        gxm = np.maximum(d[:-1, :], d[1:, :])
        gym = np.maximum(e[:, :-1], e[:, 1:])
        meta[_M_L] = float(np.max(np.hypot(gxm, gym))) / RELIEF_RES_M * (1 + 1e-6) + 1e-9
        meta[_M_HFAR] = float(H[0, 0])
    else:
        H = np.zeros((2, 2))
        n, g = 2, np.array([-ext, ext])
    meta[_M_HX0] = meta[_M_HY0] = -ext
    meta[_M_HRES] = RELIEF_RES_M if relief else 2 * ext
    meta[_M_HMIN], meta[_M_HMAX] = float(H.min()), float(H.max())
    # Kerb signed distance raster.
    if kerb:
        m = int(round(2 * ext / KERB_RES_M)) + 1
        SD = _signed_distance(drivable, -ext, m, KERB_RES_M)
        meta[_M_KH] = KERB_H
    else:
        m, SD = 2, np.full((2, 2), 1e9)
    meta[_M_SX0] = meta[_M_SY0] = -ext
    meta[_M_SRES] = KERB_RES_M if kerb else 2 * ext
    meta[_M_KW] = KERB_W
    meta[_M_FLAT] = 0.0
    return Terrain(meta, np.ascontiguousarray(H, np.float64), np.ascontiguousarray(SD, np.float64))


def _bilinear_np(grid: np.ndarray, x0: float, res: float, x: float, y: float) -> float:
    u, v = (x - x0) / res, (y - x0) / res
    j, i = int(np.floor(u)), int(np.floor(v))
    fu, fv = u - j, v - i
    return float(
        (1 - fv) * ((1 - fu) * grid[i, j] + fu * grid[i, j + 1])
        + fv * ((1 - fu) * grid[i + 1, j] + fu * grid[i + 1, j + 1])
    )


def _signed_distance(drivable, x0: float, m: int, res: float) -> np.ndarray:
    """Signed distance (m) to the boundary of ``drivable`` at the nodes of an m x m grid; negative inside.

    Exact (shapely) within 1.5 m of the boundary, a distance-transform lower bound elsewhere."""
    inside = np.zeros((m, m), np.uint8)
    polys = list(getattr(drivable, "geoms", [drivable]))
    for poly in polys:
        rings = [np.asarray(poly.exterior.coords)] + [np.asarray(r.coords) for r in poly.interiors]
        px = [np.round((r - x0) / res * 16).astype(np.int32) for r in rings]
        cv2.fillPoly(inside, px[:1], 1, cv2.LINE_8, 4)
        if len(px) > 1:
            cv2.fillPoly(inside, px[1:], 0, cv2.LINE_8, 4)
    d_out = cv2.distanceTransform((1 - inside).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    d_in = cv2.distanceTransform(inside, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    sd = np.where(inside.astype(bool), -d_in, d_out).astype(np.float64) * res
    sd = np.sign(sd) * np.maximum(np.abs(sd) - res, 0.0)  # a lower bound of the distance away from the edge
    near = np.argwhere(np.abs(sd) < 1.5)
    if len(near):
        pts = shapely.points(x0 + near[:, 1] * res, x0 + near[:, 0] * res)
        boundary = shapely.boundary(drivable)
        dist = shapely.distance(pts, boundary)
        inside_exact = shapely.contains_xy(drivable, x0 + near[:, 1] * res, x0 + near[:, 0] * res)
        sd[near[:, 0], near[:, 1]] = np.where(inside_exact, -dist, dist)
    return sd


@numba.njit(cache=True, inline="always")
def _bilinear(grid, x0, y0, res, x, y):
    """Value and gradient (d/dx, d/dy) of a node grid, clamped to its border (constant outside)."""
    ny, nx = grid.shape
    u = min(max((x - x0) / res, 0.0), nx - 1.0)
    v = min(max((y - y0) / res, 0.0), ny - 1.0)
    j = min(int(u), nx - 2)
    i = min(int(v), ny - 2)
    fu, fv = u - j, v - i
    a, b, c, d = grid[i, j], grid[i, j + 1], grid[i + 1, j], grid[i + 1, j + 1]
    val = (1 - fv) * ((1 - fu) * a + fu * b) + fv * ((1 - fu) * c + fu * d)
    gx = ((1 - fv) * (b - a) + fv * (d - c)) / res
    gy = ((1 - fu) * (c - a) + fu * (d - b)) / res
    outside_x = (x - x0) / res <= 0.0 or (x - x0) / res >= nx - 1.0
    outside_y = (y - y0) / res <= 0.0 or (y - y0) / res >= ny - 1.0
    if outside_x:
        gx = 0.0
    if outside_y:
        gy = 0.0
    return val, gx, gy


@numba.njit(cache=True, inline="always")
def surface(meta, H, SD, x, y):
    """(f-free) surface height, its gradient (gx, gy), and the kerb distance at (x, y)."""
    h, gx, gy = _bilinear(H, meta[0], meta[1], meta[2], x, y)
    sd, sx, sy = _bilinear(SD, meta[3], meta[4], meta[5], x, y)
    kh, kw = meta[7], meta[8]
    if kh > 0.0:
        r = (sd + 0.5 * kw) / kw
        if r >= 1.0:
            h += kh
        elif r > 0.0:
            h += kh * r
            gx += kh / kw * sx
            gy += kh / kw * sy
    return h, gx, gy, sd


@numba.njit(cache=True)
def _heights(meta, H, SD, xy, out):
    for i in range(xy.shape[0]):
        if meta[12] > 0.5:
            out[i] = 0.0
        else:
            out[i] = surface(meta, H, SD, xy[i, 0], xy[i, 1])[0]


@numba.njit(cache=True)
def _reliefs(meta, H, SD, xy, out):
    for i in range(xy.shape[0]):
        if meta[12] > 0.5:
            out[i] = 0.0
        else:
            out[i] = _bilinear(H, meta[0], meta[1], meta[2], xy[i, 0], xy[i, 1])[0]


@numba.njit(cache=True)
def _normals(meta, H, SD, xy, out):
    for i in range(xy.shape[0]):
        gx, gy = 0.0, 0.0
        if meta[12] < 0.5:
            _, gx, gy, _ = surface(meta, H, SD, xy[i, 0], xy[i, 1])
        nrm = np.sqrt(gx * gx + gy * gy + 1.0)
        out[i, 0], out[i, 1], out[i, 2] = -gx / nrm, -gy / nrm, 1.0 / nrm


@numba.njit(cache=True, inline="always")
def _gap(meta, H, SD, ox, oy, oz, dx, dy, dz, t):
    h, gx, gy, sd = surface(meta, H, SD, ox + t * dx, oy + t * dy)
    return oz + t * dz - h, gx, gy, sd


@numba.njit(cache=True)
def ray_terrain(meta, H, SD, ox, oy, oz, dx, dy, dz, t_min, t_max):
    """First t in [t_min, t_max] where the ray meets the surface (inf if none)."""
    if meta[12] > 0.5:  # flat: the plane z = 0, as the original renderer computes it
        if abs(dz) > 1e-12:
            t = -oz / dz
            if t > t_min and t <= t_max:
                return t
        return np.inf
    kh, kw = meta[7], meta[8]
    top = meta[10] + kh
    dh = np.sqrt(dx * dx + dy * dy)
    t = t_min
    if oz + t * dz > top:
        if dz >= 0.0:
            return np.inf
        t = max(t_min, (oz - top) / (-dz))
    rate = meta[6] * dh - dz  # bound on how fast z - H can shrink per unit t
    kerb_rate = kh / kw * _SQRT2 * dh
    # Beyond both rasters the surface is the plane z = far + kerb height.
    hx1 = meta[0] + (H.shape[1] - 1) * meta[2]
    hy1 = meta[1] + (H.shape[0] - 1) * meta[2]
    sx1 = meta[3] + (SD.shape[1] - 1) * meta[5]
    sy1 = meta[4] + (SD.shape[0] - 1) * meta[5]
    bx0, by0 = max(meta[0], meta[3]), max(meta[1], meta[4])
    bx1, by1 = min(hx1, sx1), min(hy1, sy1)
    f, gx, gy, sd = _gap(meta, H, SD, ox, oy, oz, dx, dy, dz, t)
    if f <= 0.0:
        return t
    t_lo = t
    for _ in range(_MAX_STEPS):
        if t > t_max:
            return np.inf
        x, y = ox + t * dx, oy + t * dy
        if (
            (x <= bx0 and dx <= 0.0)
            or (x >= bx1 and dx >= 0.0)
            or (y <= by0 and dy <= 0.0)
            or (y >= by1 and dy >= 0.0)
        ):
            z_far = meta[11] + kh
            if dz < 0.0:
                th = t + (oz + t * dz - z_far) / (-dz)
                return th if th <= t_max else np.inf
            return np.inf
        if f < _F_DONE:
            return t
        k = 0.0
        if kh > 0.0:
            r = (sd + 0.5 * kw) / kw
            k = kh if r >= 1.0 else (kh * r if r > 0.0 else 0.0)
        step_a = np.inf if rate <= 0.0 else (f - (kh - k)) / rate
        if rate <= 0.0 and f <= kh - k:
            step_a = 0.0
        away = abs(sd) - 0.5 * kw
        if kh <= 0.0:
            step_b = np.inf if rate <= 0.0 else f / rate
            away = np.inf
        elif away > 0.0:
            d_kerb = away / (_SQRT2 * dh) if dh > 0.0 else np.inf
            step_b = min(d_kerb, f / rate) if rate > 0.0 else d_kerb
        else:
            r2 = rate + kerb_rate
            step_b = f / r2 if r2 > 0.0 else np.inf
        step = max(step_a, step_b)
        if f < _F_NEWTON and away > 0.0:
            act = -(dz - (gx * dx + gy * dy))  # actual rate of approach
            if act > 0.0:
                newton = f / act
                if kh > 0.0 and dh > 0.0:
                    newton = min(newton, away / (_SQRT2 * dh))
                step = max(step, newton)
        if step == np.inf:
            return np.inf
        step = max(step, 1e-9 * (1.0 + t))
        t_lo = t
        t = t + step
        f, gx, gy, sd = _gap(meta, H, SD, ox, oy, oz, dx, dy, dz, t)
        if f <= 0.0:  # a Newton step overshot: bracketed regula falsi (Illinois) on [t_lo, t]
            a, fa = t_lo, _gap(meta, H, SD, ox, oy, oz, dx, dy, dz, t_lo)[0]
            b, fb = t, f
            side = 0
            for _ in range(40):
                c = b - fb * (b - a) / (fb - fa) if fb != fa else 0.5 * (a + b)
                fc = _gap(meta, H, SD, ox, oy, oz, dx, dy, dz, c)[0]
                if abs(fc) < _F_DONE or b - a < 1e-9 * (1.0 + c):
                    return c
                if fc > 0.0:
                    a, fa = c, fc
                    if side == 1:
                        fb *= 0.5
                    side = 1
                else:
                    b, fb = c, fc
                    if side == -1:
                        fa *= 0.5
                    side = -1
            return 0.5 * (a + b)
    return t if f < 0.05 else np.inf


@numba.njit(cache=True, parallel=True)
def _intersect_many(meta, H, SD, origin, dirs, t_min, t_max, out):
    for j in numba.prange(dirs.shape[0]):
        out[j] = ray_terrain(
            meta, H, SD, origin[0], origin[1], origin[2], dirs[j, 0], dirs[j, 1], dirs[j, 2], t_min, t_max
        )
