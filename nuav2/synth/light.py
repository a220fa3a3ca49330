"""Sun and sky of the synthetic world, and the cast-shadow test.

Without the ``shadows`` factor the sun is the original fixed direction (Lambert shading, no
cast shadows) and the sky a gradient by elevation. With it, the sun's azimuth and elevation
come from the seed, every lit point (ground and solids) casts a ray to the sun against the
solids, and the sky adds a glow around the sun and clouds (fractal value noise on a cloud deck),
so it depends on direction, not on elevation alone.

Shadow rays are culled with a grid: each solid's corners projected along the sun onto z = 0
bound every point it can shade once that point is projected the same way (the shadow ray of a
point projects to a single point), so a query tests only the solids listed in one cell.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from nuav2.geometry import F64
from nuav2.synth.boxes import BoxSet, solid_hit
from nuav2.synth.materials import value_noise3

LEGACY_SUN = np.array([0.35, -0.45, 0.82]) / np.linalg.norm([0.35, -0.45, 0.82])
AMBIENT, DIRECT = 0.45, 0.55
SKY_TOP_SIN = float(np.sin(np.pi / 3))  # the sky gradient saturates at 60 degrees elevation
SKY_HORIZON = np.array([205.0, 218.0, 232.0])
SKY_ZENITH = np.array([88.0, 136.0, 205.0])
GLOW = np.array([255.0, 244.0, 222.0])
CLOUD_LIT = np.array([238.0, 238.0, 242.0])
CLOUD_DARK = np.array([168.0, 172.0, 184.0])
CLOUD_DECK_M = 1500.0
SHADOW_CELL_M = 2.0
SHADOW_EPS_M = 0.01


@dataclass(frozen=True)
class Sky:
    """Sun direction (local frame, unit, up = +z) and the sky's parameters."""

    sun: F64  # (3,)
    structured: bool  # glow + clouds (shadows factor), else the elevation gradient
    cloud_cover: float = 0.0  # noise threshold: fraction of the sky without cloud, roughly
    cloud_offset: tuple[float, float] = (0.0, 0.0)

    def packed(self) -> F64:
        return np.array([*self.sun, float(self.structured), self.cloud_cover, *self.cloud_offset])


def make_sky(rng: np.random.Generator | None) -> Sky:
    """The seed's sun and clouds (``rng`` None: the original fixed sun, gradient sky)."""
    if rng is None:
        return Sky(LEGACY_SUN, False)
    az, el = rng.uniform(-np.pi, np.pi), np.deg2rad(rng.uniform(30.0, 62.0))
    sun = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    return Sky(
        sun, True, float(rng.uniform(0.45, 0.7)), (float(rng.uniform(0, 1e4)), float(rng.uniform(0, 1e4)))
    )


@numba.njit(cache=True)
def sky_color(sky, dx, dy, dz, out, j):
    """Sky colour of direction (dx, dy, dz) into out[j]."""
    norm = np.sqrt(dx * dx + dy * dy + dz * dz)
    elev = dz / norm
    s = min(max(elev / SKY_TOP_SIN, 0.0), 1.0) ** 0.7
    for c in range(3):
        out[j, c] = SKY_HORIZON[c] + (SKY_ZENITH[c] - SKY_HORIZON[c]) * s
    if sky[3] < 0.5:
        return
    cos_sun = (dx * sky[0] + dy * sky[1] + dz * sky[2]) / norm
    glow = 0.6 * np.exp((cos_sun - 1.0) / 0.004) + 0.3 * np.exp((cos_sun - 1.0) / 0.12)
    glow = min(glow, 1.0)
    for c in range(3):
        out[j, c] += (GLOW[c] - out[j, c]) * glow
    if elev > 0.015:
        k = CLOUD_DECK_M / dz / 400.0  # the cloud deck point, in 400 m noise cells
        cx = dx * k + sky[5]
        cy = dy * k + sky[6]
        n = (
            0.55 * value_noise3(cx, cy, 0.5)
            + 0.3 * value_noise3(cx * 2.7, cy * 2.7, 3.5)
            + 0.15 * value_noise3(cx * 7.3, cy * 7.3, 9.5)
        )
        cover = sky[4]
        a = min(max((n - cover) / 0.18, 0.0), 1.0)
        a *= min(elev / 0.12, 1.0)  # clouds fade into the haze toward the horizon
        dense = min(max((n - cover) / 0.35, 0.0), 1.0)
        for c in range(3):
            cloud = CLOUD_LIT[c] + (CLOUD_DARK[c] - CLOUD_LIT[c]) * dense
            out[j, c] += (cloud - out[j, c]) * a


@dataclass(frozen=True, eq=False)
class ShadowGrid:
    """Solids listed per cell of a grid over their sun-projected bounds (CSR)."""

    meta: F64  # x0, y0, cell, nx, ny
    start: np.ndarray  # (nx * ny + 1,) int64
    items: np.ndarray  # int64 solid indices

    def arrays(self) -> tuple[F64, np.ndarray, np.ndarray]:
        return self.meta, self.start, self.items


def shadow_grid(solids: BoxSet, sun: F64, casts: np.ndarray | None = None) -> ShadowGrid:
    """The grid for ``solids`` lit by ``sun``; ``casts`` (N,) bool: which solids cast shadows."""
    idx = np.arange(len(solids)) if casts is None else np.flatnonzero(casts)
    if len(idx) == 0:
        return ShadowGrid(np.array([0.0, 0.0, 1.0, 1.0, 1.0]), np.zeros(2, np.int64), np.zeros(0, np.int64))
    corners = solids.subset(idx).corners()  # (N, 8, 3)
    proj = corners[..., :2] - sun[:2] * (corners[..., 2:3] / sun[2])
    lo, hi = proj.min(axis=1), proj.max(axis=1)
    x0, y0 = lo.min(axis=0) - 1.0
    span = hi.max(axis=0) + 1.0 - (x0, y0)
    cell = max(SHADOW_CELL_M, float(span.max()) / 1024.0)
    nx, ny = int(np.ceil(span[0] / cell)) + 1, int(np.ceil(span[1] / cell)) + 1
    c0 = np.floor((lo - (x0, y0)) / cell).astype(np.int64)
    c1 = np.floor((hi - (x0, y0)) / cell).astype(np.int64)
    counts = np.zeros(nx * ny + 1, np.int64)
    _count_cells(c0, c1, nx, counts)
    start = np.concatenate([[0], np.cumsum(counts[:-1])])
    items = np.empty(int(start[-1]), np.int64)
    _fill_cells(c0, c1, nx, idx.astype(np.int64), start.copy(), items)
    return ShadowGrid(np.array([x0, y0, cell, nx, ny], np.float64), start, items)


@numba.njit(cache=True)
def _count_cells(c0, c1, nx, counts):
    for i in range(c0.shape[0]):
        for cy in range(c0[i, 1], c1[i, 1] + 1):
            for cx in range(c0[i, 0], c1[i, 0] + 1):
                counts[cy * nx + cx] += 1


@numba.njit(cache=True)
def _fill_cells(c0, c1, nx, idx, cursor, items):
    for i in range(c0.shape[0]):
        for cy in range(c0[i, 1], c1[i, 1] + 1):
            for cx in range(c0[i, 0], c1[i, 0] + 1):
                items[cursor[cy * nx + cx]] = idx[i]
                cursor[cy * nx + cx] += 1


@numba.njit(cache=True)
def in_shadow(gmeta, gstart, gitems, centers, rots, halves, quads, sun, px, py, pz):
    """True if the ray from (px, py, pz) toward the sun hits any listed solid."""
    if gstart.shape[0] < 2 or sun[2] <= 0.0:
        return False
    qx = px - sun[0] * pz / sun[2]
    qy = py - sun[1] * pz / sun[2]
    cell = gmeta[2]
    cx = int(np.floor((qx - gmeta[0]) / cell))
    cy = int(np.floor((qy - gmeta[1]) / cell))
    nx, ny = int(gmeta[3]), int(gmeta[4])
    if cx < 0 or cy < 0 or cx >= nx or cy >= ny:
        return False
    c = cy * nx + cx
    for k in range(gstart[c], gstart[c + 1]):
        i = gitems[k]
        R = rots[i]
        rx, ry, rz = px - centers[i, 0], py - centers[i, 1], pz - centers[i, 2]
        ox = R[0, 0] * rx + R[1, 0] * ry + R[2, 0] * rz
        oy = R[0, 1] * rx + R[1, 1] * ry + R[2, 1] * rz
        oz = R[0, 2] * rx + R[1, 2] * ry + R[2, 2] * rz
        bx = R[0, 0] * sun[0] + R[1, 0] * sun[1] + R[2, 0] * sun[2]
        by = R[0, 1] * sun[0] + R[1, 1] * sun[1] + R[2, 1] * sun[2]
        bz = R[0, 2] * sun[0] + R[1, 2] * sun[1] + R[2, 2] * sun[2]
        t, face = solid_hit(
            ox,
            oy,
            oz,
            bx,
            by,
            bz,
            halves[i, 0],
            halves[i, 1],
            halves[i, 2],
            quads[i, 0],
            quads[i, 1],
            quads[i, 2],
            0.0,
        )
        if face >= 0 and t > 0.0:
            return True
    return False
