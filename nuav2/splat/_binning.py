"""Numba tile binning: per 16x16 tile, the ids of the Gaussians that can touch it, nearest first.

The Gaussians are depth-sorted once (one sort of N keys) and then scattered into tiles by a
stable counting sort, so every tile list comes out depth-ordered without sorting N*tiles
keys. A Gaussian enters a tile only if its ellipse {sigma <= ln(255 o) + margin} reaches one
of the tile's pixel centres: per tile row the exact x-extent of the ellipse within the row
is computed, which drops the empty corners of the rectangular bounding box.

Binning runs slab by slab in depth order (a few hundred nearest rows first, then slabs
growing 4x), interleaved with compositing: a slab is binned only into tiles that still have a
live pixel. Behind near, opaque splats almost every tile has stopped after the first slab, so
the pairs that could never contribute are never written (8.4 M -> 0.14 M on the benchmark's
near-splat scene at 480x270, `nuav2 bench raster`, field tile_pairs).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from nuav2.splat._composite import P_A, P_B, P_C, P_EX, P_EY, P_MX, P_MY, P_THR, band_x_extent
from nuav2.splat.constants import TILE

MIN_SLAB = 256
FIRST_SLAB_DIVISOR = 256
SLAB_GROWTH = 4


@njit(cache=True, inline="always")
def _tile_range(m, e, n_tiles_axis, size):
    """Tiles [lo, hi) holding pixel centres j + 0.5 with |j + 0.5 - m| <= e (e = inf: all)."""
    if not (e < 1e30):
        return 0, n_tiles_axis
    lo = max(0.0, np.ceil(m - e - 0.5))
    hi = min(size - 1.0, np.floor(m + e - 0.5))
    if hi < lo:
        return 0, 0
    return int(lo) // TILE, int(hi) // TILE + 1


@njit(cache=True, inline="always")
def _row_span(mx, my, a, b, c, thresh, ex, ey, ty, tx0, tx1, width, height):
    """Tiles [lo, hi), within [tx0, tx1), of tile row ty that the ellipse {sigma <= thresh} reaches."""
    if tx1 <= tx0:
        return 0, 0
    x_lo, x_hi = band_x_extent(ty * TILE + 0.5 - my, min((ty + 1) * TILE, height) - 0.5 - my, a, b, c,
                               thresh, ex, ey)
    if x_lo > x_hi:
        return 0, 0
    lo = max(0.0, np.ceil(mx + x_lo - 0.5))
    hi = min(width - 1.0, np.floor(mx + x_hi - 0.5))
    if hi < lo:
        return 0, 0
    return max(tx0, int(lo) // TILE), min(tx1, int(hi) // TILE + 1)


@njit(cache=True, inline="always")
def _row(packed, g):
    return (np.float64(packed[g, P_MX]), np.float64(packed[g, P_MY]), np.float64(packed[g, P_A]),
            np.float64(packed[g, P_B]), np.float64(packed[g, P_C]), np.float64(packed[g, P_THR]),
            np.float64(packed[g, P_EX]), np.float64(packed[g, P_EY]))


@njit(parallel=True, cache=True, nogil=True)
def bin_rows(packed, base, lo, hi, width, height, tile_alive, n_groups):
    """Tile offsets (n_tiles+1,) and, per live tile, the rows lo..hi-1 that touch it (row k is
    packed[k - base]).

    ``packed`` holds the visible Gaussians nearest first (rows from
    :func:`nuav2.splat._composite.pack_rows`, permuted by :func:`depth_order`), so rows
    are read sequentially and every tile list comes out ascending, i.e. depth-ordered: a
    stable counting sort by tile (count pass, prefix sum, write pass), split over
    ``n_groups`` contiguous row blocks. Tiles with tile_alive[t] == 0 (every pixel already
    stopped) get no entries; per tile row only the span between its first and last live tile
    is visited, so a splat behind an opaque region costs a few range checks, not a pair per tile.
    """
    tiles_x = (width + TILE - 1) // TILE
    tiles_y = (height + TILE - 1) // TILE
    n_tiles = tiles_x * tiles_y
    live_lo = np.zeros(tiles_y, np.int64)
    live_hi = np.zeros(tiles_y, np.int64)
    for ty in range(tiles_y):
        first = tiles_x
        end = 0
        for tx in range(tiles_x):
            if tile_alive[ty * tiles_x + tx] != 0:
                first = min(first, tx)
                end = tx + 1
        live_lo[ty] = first
        live_hi[ty] = end
    n = hi - lo
    per_group = (n + n_groups - 1) // n_groups
    counts = np.zeros((n_groups, n_tiles), np.int64)
    for p in prange(n_groups):
        for k in range(lo + p * per_group, min(hi, lo + (p + 1) * per_group)):
            mx, my, a, b, c, thresh, ex, ey = _row(packed, k - base)
            tx0, tx1 = _tile_range(mx, ex, tiles_x, width)
            ty0, ty1 = _tile_range(my, ey, tiles_y, height)
            for ty in range(ty0, ty1):
                s0, s1 = _row_span(mx, my, a, b, c, thresh, ex, ey, ty, max(tx0, live_lo[ty]),
                                   min(tx1, live_hi[ty]), width, height)
                for tx in range(s0, s1):
                    t = ty * tiles_x + tx
                    counts[p, t] += tile_alive[t]
    offsets = np.zeros(n_tiles + 1, np.int64)
    cursors = np.empty((n_groups, n_tiles), np.int64)
    total = 0
    for t in range(n_tiles):
        offsets[t] = total
        for p in range(n_groups):
            cursors[p, t] = total
            total += counts[p, t]
    offsets[n_tiles] = total
    ids = np.empty(total, np.int32)
    for p in prange(n_groups):
        for k in range(lo + p * per_group, min(hi, lo + (p + 1) * per_group)):
            mx, my, a, b, c, thresh, ex, ey = _row(packed, k - base)
            tx0, tx1 = _tile_range(mx, ex, tiles_x, width)
            ty0, ty1 = _tile_range(my, ey, tiles_y, height)
            for ty in range(ty0, ty1):
                s0, s1 = _row_span(mx, my, a, b, c, thresh, ex, ey, ty, max(tx0, live_lo[ty]),
                                   min(tx1, live_hi[ty]), width, height)
                for tx in range(s0, s1):
                    t = ty * tiles_x + tx
                    if tile_alive[t] != 0:
                        ids[cursors[p, t]] = k
                        cursors[p, t] += 1
    return offsets, ids


def bin_slab(packed: np.ndarray, lo: int, hi: int, width: int, height: int, tile_alive: np.ndarray,
             n_groups: int) -> tuple[np.ndarray, np.ndarray]:
    """Tile offsets and row ids of rows [lo, hi) for depth-sorted packed rows of either dtype.

    float64 rows are binned from a float32 copy, so only one kernel is ever compiled: the
    reject margin in the packed threshold (0.01 in the exponent) dwarfs float32 rounding, so
    no contributing pair can be lost (values past the float32 range become inf, which only
    widens a Gaussian's tile range).
    """
    base = 0
    if packed.dtype != np.float32:
        with np.errstate(over="ignore"):
            packed = packed[lo:hi, :P_EY + 1].astype(np.float32)     # columns 13-15 are padding
        base = lo
    return bin_rows(packed, base, int(lo), int(hi), int(width), int(height), tile_alive, int(n_groups))


def slab_bounds(n_rows: int) -> list[int]:
    """Row boundaries of the depth slabs: the first 1/FIRST_SLAB_DIVISOR of the rows (at least
    MIN_SLAB), then each slab SLAB_GROWTH times the previous one.

    Small front slabs let near opaque splats stop whole tiles before the Gaussians behind them
    are binned; growing slabs keep the number of passes logarithmic in N.
    """
    bounds = [0]
    size = max(MIN_SLAB, n_rows // FIRST_SLAB_DIVISOR)
    while bounds[-1] < n_rows:
        bounds.append(min(n_rows, bounds[-1] + size))
        size *= SLAB_GROWTH
    return bounds


def n_tiles(width: int, height: int) -> int:
    """Number of TILE x TILE tiles covering a width x height image."""
    return ((width + TILE - 1) // TILE) * ((height + TILE - 1) // TILE)


def depth_order(depths: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """Ids of the visible Gaussians (radii > 0), nearest first, ties by id.

    Sorts unique int64 keys (float32 depth bits << 32 | id; depths are > near > 0 so their bit
    patterns order like the values), which numpy sorts with its SIMD quicksort: deterministic
    and equal to a stable argsort by depth.
    """
    visible = np.flatnonzero((radii[:, 0] > 0) | (radii[:, 1] > 0))
    bits = depths[visible].astype(np.float32).view(np.int32).astype(np.int64)
    keys = np.sort((bits << 32) | visible)
    return keys & 0xFFFFFFFF
