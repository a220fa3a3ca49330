"""Ground height between raster cells: bilinear across cell centres, so slopes and crests are smooth.

AV2's ground-height raster stores one height per 30 cm cell (its centre); reading the cell a point
falls in makes a staircase on a slope (2.4 cm steps at 8 %, plus float16 rounding). Both
re-rendering modes read heights here (warp mode's compiled ray caster mirrors it in
``nuav2.warp._kernels``). Neighbours without a value (outside the raster's region of interest)
are left out and the others renormalised, so the region's edge never pulls in a NaN; a point
with no valid neighbour gets NaN.
"""

from __future__ import annotations

import numpy as np

from nuav2.scene import GroundHeightRaster

F64 = np.ndarray


def bilinear_height(raster: GroundHeightRaster, xy_city: F64) -> F64:
    """(N,) ground z at (N, 2) city points, bilinear between the valid neighbouring cell centres."""
    xy = np.asarray(xy_city, np.float64).reshape(-1, 2)
    p = raster.s * (xy @ raster.R.T + raster.t) - 0.5  # cell-centre coordinates
    c0, r0 = np.floor(p[:, 0]).astype(np.int64), np.floor(p[:, 1]).astype(np.int64)
    fx, fy = p[:, 0] - c0, p[:, 1] - r0
    h, w = raster.heights.shape
    acc, wsum = np.zeros(len(xy)), np.zeros(len(xy))
    for dr, dc, wgt in ((0, 0, (1 - fx) * (1 - fy)), (0, 1, fx * (1 - fy)), (1, 0, (1 - fx) * fy),
                        (1, 1, fx * fy)):
        r, c = r0 + dr, c0 + dc
        ok = (r >= 0) & (r < h) & (c >= 0) & (c < w)
        v = np.full(len(xy), np.nan)
        v[ok] = raster.heights[r[ok], c[ok]]
        good = np.isfinite(v) & (wgt > 0)
        acc[good] += wgt[good] * v[good]
        wsum[good] += wgt[good]
    out = np.full(len(xy), np.nan)
    has = wsum > 1e-12
    out[has] = acc[has] / wsum[has]
    return out
