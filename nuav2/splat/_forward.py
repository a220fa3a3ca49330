"""Numba front-to-back alpha compositing of one depth slab of Gaussians into persistent images.

The renderer feeds the depth-sorted Gaussians slab by slab (nearest first, see
:mod:`nuav2.splat._binning`); each call composites one slab's tile lists on top of the
per-pixel state left by the slabs in front (transmittance T, colour and depth sums, last
contributor, stopped flag) and reports which tiles still have a live pixel, so the next slab
is binned only into those. Per tile: 16 sub-blocks of 4x4 pixel lanes; a Gaussian visits only
the sub-blocks its ellipse's bounding box reaches that still have a live pixel; the tile stops
once every pixel has stopped.
"""

from __future__ import annotations

import numpy as np
from numba import prange

from nuav2.splat._composite import (
    C_AMAX,
    C_AMIN,
    C_HALF,
    C_ONE,
    C_TSTOP,
    C_ZERO,
    LANES,
    N_SUBS,
    P_EX,
    P_EY,
    SUBS_PER_SIDE,
    lane_pixel,
    parallel_and_serial,
    row_data,
    sub_range,
)
from nuav2.splat._fastexp import exp_neg_lanes
from nuav2.splat.constants import TILE


def _composite_slab(packed, offsets, ids, tiles, px_centres, py_centres, n_groups, consts,
                    color, depth, T_img, last_img, done_img, tile_alive):
    """Composite the tile lists ``ids[offsets[t]:offsets[t+1]]`` of the tiles in ``tiles`` onto
    the image state: colour sum (H,W,3), depth sum (H,W), T (H,W), last contributing row (H,W,
    -1 none), done (H,W; 1 once the pixel stopped); sets tile_alive[t] to 0 once every pixel of
    tile t has stopped."""
    height, width = T_img.shape
    tiles_x = (width + TILE - 1) // TILE
    n_work = tiles.shape[0]
    half = consts[C_HALF]
    one = consts[C_ONE]
    zero = consts[C_ZERO]
    amin = consts[C_AMIN]
    amax = consts[C_AMAX]
    tstop = consts[C_TSTOP]
    dt = T_img.dtype
    L = LANES
    NS = 7 * L            # float lane state per sub-block: px, py, T, r, g, b, depth
    NI = 2 * L            # int lane state per sub-block: last contributing row, alive
    zero_i = np.int32(0)  # 32-bit lane integers: a 64-bit one would halve the vector width
    for p in prange(n_groups):
        # one float and one int buffer: fewer arrays, fewer aliasing checks around the lane loop
        st = np.empty(N_SUBS * NS, dt)
        ist = np.empty(N_SUBS * NI, np.int32)
        sub_alive = np.empty(N_SUBS, np.int64)
        for k in range(p, n_work, n_groups):
            t = tiles[k]
            ty = t // tiles_x
            tx = t - ty * tiles_x
            live_subs = 0
            for sb in range(N_SUBS):
                base = sb * NS
                n_live = 0
                for l in range(L):
                    ix, iy = lane_pixel(tx, ty, sb, l)
                    inside = ix < width and iy < height
                    ix = min(ix, width - 1)
                    iy = min(iy, height - 1)
                    st[base + l] = px_centres[ix]
                    st[base + L + l] = py_centres[iy]
                    st[base + 2 * L + l] = T_img[iy, ix]
                    st[base + 3 * L + l] = color[iy, ix, 0]
                    st[base + 4 * L + l] = color[iy, ix, 1]
                    st[base + 5 * L + l] = color[iy, ix, 2]
                    st[base + 6 * L + l] = depth[iy, ix]
                    ist[sb * NI + l] = last_img[iy, ix]
                    live = 1 if (inside and done_img[iy, ix] == 0) else 0
                    ist[sb * NI + L + l] = live
                    n_live += live
                sub_alive[sb] = n_live
                live_subs += 1 if n_live > 0 else 0
            for j in range(offsets[t], offsets[t + 1]):
                if live_subs == 0:
                    break
                g = ids[j]
                mx, my, a, b, c, o, thr, cr, cg, cb, z = row_data(packed, g)
                bx0, bx1 = sub_range(mx, packed[g, P_EX], tx * TILE)
                by0, by1 = sub_range(my, packed[g, P_EY], ty * TILE)
                gg = np.int32(g)
                for by in range(by0, by1 + 1):
                    for bx in range(bx0, bx1 + 1):
                        sb = by * SUBS_PER_SIDE + bx
                        if sub_alive[sb] == 0:
                            continue
                        sst = st[sb * NS:(sb + 1) * NS]
                        sint = ist[sb * NI:(sb + 1) * NI]
                        n_live = np.int32(0)
                        for l in range(L):
                            dx = mx - sst[l]
                            dy = my - sst[L + l]
                            s = half * (a * dx * dx + c * dy * dy) + b * dx * dy
                            ok = (s >= zero) and (s <= thr) and (sint[L + l] != 0)
                            alpha = min(amax, o * exp_neg_lanes(s if ok else zero))
                            ok = ok and (alpha >= amin)
                            T = sst[2 * L + l]
                            next_T = T * (one - alpha)
                            stop = ok and (next_T <= tstop)
                            use = ok and not stop
                            w = alpha * T if use else zero
                            sst[3 * L + l] += w * cr
                            sst[4 * L + l] += w * cg
                            sst[5 * L + l] += w * cb
                            sst[6 * L + l] += w * z
                            sst[2 * L + l] = next_T if use else T
                            sint[l] = gg if use else sint[l]
                            sint[L + l] = zero_i if stop else sint[L + l]
                        for l in range(L):                # a reduction inside the lane loop
                            n_live += sint[L + l]         # would halve its vector width
                        sub_alive[sb] = n_live
                        if n_live == 0:
                            live_subs -= 1
            for sb in range(N_SUBS):
                base = sb * NS
                for l in range(L):
                    ix, iy = lane_pixel(tx, ty, sb, l)
                    if ix < width and iy < height:
                        T_img[iy, ix] = st[base + 2 * L + l]
                        color[iy, ix, 0] = st[base + 3 * L + l]
                        color[iy, ix, 1] = st[base + 4 * L + l]
                        color[iy, ix, 2] = st[base + 5 * L + l]
                        depth[iy, ix] = st[base + 6 * L + l]
                        last_img[iy, ix] = ist[sb * NI + l]
                        done_img[iy, ix] = 1 - ist[sb * NI + L + l]
            tile_alive[t] = 1 if live_subs > 0 else 0


composite_slab, composite_slab_serial = parallel_and_serial(_composite_slab)


def slab_kernel(dtype):
    """The slab compositor for an image dtype (parallel float32, serial float64)."""
    return composite_slab if np.dtype(dtype) == np.float32 else composite_slab_serial
