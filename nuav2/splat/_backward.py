"""Numba backward of the compositor: back to front from each pixel's last contributor, exact.

Per tile the depth slabs' lists are walked in reverse (rows are depth-ordered, so a row id
larger than a pixel's last contributor is behind it and skipped). T is recovered by dividing
by (1 - alpha) with the forward's clamps; per-lane "colour behind" sums give dL/dalpha. A
Gaussian's 12 gradient channels are accumulated over its sub-blocks, the 16 lanes summed by
a fixed pairwise tree (deterministic) and added into the work group's buffer: no atomics.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from nuav2.splat._composite import (
    C_AMAX,
    C_AMIN,
    C_HALF,
    C_ONE,
    C_ZERO,
    G_A,
    G_ABS_MX,
    G_ABS_MY,
    G_B,
    G_BL,
    G_C,
    G_G,
    G_MX,
    G_MY,
    G_O,
    G_R,
    G_Z,
    LANES,
    N_GRAD,
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


@njit(cache=True, inline="always")
def _lane_sums_into(buf, grads, p, g):
    """grads[p, g, ch] += sum of the 16 lanes buf[ch*16 : ch*16+16], by a fixed pairwise tree
    (deterministic; the channel-inner loops vectorise better than one tree per channel)."""
    for l in range(8):
        for ch in range(N_GRAD):
            buf[ch * LANES + l] += buf[ch * LANES + l + 8]
    for l in range(4):
        for ch in range(N_GRAD):
            buf[ch * LANES + l] += buf[ch * LANES + l + 4]
    for ch in range(N_GRAD):
        o = ch * LANES
        grads[p, g, ch] += (buf[o] + buf[o + 2]) + (buf[o + 1] + buf[o + 3])


def _composite_backward(packed, slab_offsets, ids, tile_order, px_centres, py_centres, n_groups, consts,
                        T_img, last_img, g_color, g_depth, g_alpha, grads, contributions):
    """Add dL/d(per-Gaussian inputs) into grads (n_groups, rows, 12) given dL/d(outputs), and the
    number of Gaussian-pixel contributions each group visited into contributions (n_groups,).

    slab_offsets (n_slabs, n_tiles + 1): tile t's list in slab s is
    ids[slab_offsets[s, t]:slab_offsets[s, t + 1]]; last_img holds each pixel's last
    contributing row (-1 for none)."""
    height, width = T_img.shape
    tiles_x = (width + TILE - 1) // TILE
    n_tiles = tile_order.shape[0]
    n_slabs = slab_offsets.shape[0]
    half = consts[C_HALF]
    one = consts[C_ONE]
    zero = consts[C_ZERO]
    amin = consts[C_AMIN]
    amax = consts[C_AMAX]
    dt = T_img.dtype
    L = LANES
    # lane state per sub-block: px, py, T, S_r, S_g, S_b, S_depth, dL/dr, dL/dg, dL/db, dL/ddepth,
    # dL/dalpha * T_final (S = colour/depth accumulated behind the current Gaussian)
    NS = 12 * L
    one_i = np.int32(1)
    zero_i = np.int32(0)
    for p in prange(n_groups):
        st = np.empty(N_SUBS * NS, dt)
        last = np.empty(N_SUBS * L, np.int32)
        sub_hi = np.empty(N_SUBS, np.int64)
        buf = np.empty(N_GRAD * L, dt)
        okl = np.empty(L, np.int32)
        for k in range(p, n_tiles, n_groups):
            t = tile_order[k]
            ty = t // tiles_x
            tx = t - ty * tiles_x
            tile_hi = -1
            for sb in range(N_SUBS):
                base = sb * NS
                hi = -1
                for l in range(L):
                    ix, iy = lane_pixel(tx, ty, sb, l)
                    inside = ix < width and iy < height
                    ix = min(ix, width - 1)
                    iy = min(iy, height - 1)
                    T_final = T_img[iy, ix]
                    st[base + l] = px_centres[ix]
                    st[base + L + l] = py_centres[iy]
                    st[base + 2 * L + l] = T_final
                    st[base + 3 * L + l] = zero
                    st[base + 4 * L + l] = zero
                    st[base + 5 * L + l] = zero
                    st[base + 6 * L + l] = zero
                    st[base + 7 * L + l] = g_color[iy, ix, 0]
                    st[base + 8 * L + l] = g_color[iy, ix, 1]
                    st[base + 9 * L + l] = g_color[iy, ix, 2]
                    st[base + 10 * L + l] = g_depth[iy, ix]
                    st[base + 11 * L + l] = g_alpha[iy, ix] * T_final
                    lst = last_img[iy, ix] if inside else -1
                    last[sb * L + l] = lst
                    hi = max(hi, lst)
                sub_hi[sb] = hi
                tile_hi = max(tile_hi, hi)
            for s in range(n_slabs - 1, -1, -1):
                for j in range(slab_offsets[s, t + 1] - 1, slab_offsets[s, t] - 1, -1):
                    g = ids[j]
                    if g > tile_hi:
                        continue
                    mx, my, a, b, c, o, thr, cr, cg, cb, z = row_data(packed, g)
                    bx0, bx1 = sub_range(mx, packed[g, P_EX], tx * TILE)
                    by0, by1 = sub_range(my, packed[g, P_EY], ty * TILE)
                    gg = np.int32(g)
                    n_ok = np.int32(0)
                    buf[:] = zero
                    for by in range(by0, by1 + 1):
                        for bx in range(bx0, bx1 + 1):
                            sb = by * SUBS_PER_SIDE + bx
                            if g > sub_hi[sb]:
                                continue
                            sst = st[sb * NS:(sb + 1) * NS]
                            slast = last[sb * L:(sb + 1) * L]
                            for l in range(L):
                                dx = mx - sst[l]
                                dy = my - sst[L + l]
                                sg = half * (a * dx * dx + c * dy * dy) + b * dx * dy
                                ok = (sg >= zero) and (sg <= thr) and (gg <= slast[l])
                                e = exp_neg_lanes(sg if ok else zero)
                                raw = o * e
                                alpha = min(amax, raw)
                                ok = ok and (alpha >= amin)
                                inv_one_m = one / (one - alpha)
                                T = sst[2 * L + l] * inv_one_m if ok else sst[2 * L + l]
                                sst[2 * L + l] = T
                                w = alpha * T if ok else zero
                                gr = sst[7 * L + l]
                                ggr = sst[8 * L + l]
                                gb = sst[9 * L + l]
                                gd = sst[10 * L + l]
                                g_alpha_j = (T * (cr * gr + cg * ggr + cb * gb + z * gd)
                                             - (sst[3 * L + l] * gr + sst[4 * L + l] * ggr
                                                + sst[5 * L + l] * gb + sst[6 * L + l] * gd
                                                - sst[11 * L + l]) * inv_one_m)
                                sst[3 * L + l] += w * cr
                                sst[4 * L + l] += w * cg
                                sst[5 * L + l] += w * cb
                                sst[6 * L + l] += w * z
                                free = ok and raw <= amax                 # alpha not clamped at 0.999
                                g_s = -g_alpha_j * alpha if free else zero
                                gmx = g_s * (a * dx + b * dy)
                                gmy = g_s * (b * dx + c * dy)
                                buf[G_MX * L + l] += gmx
                                buf[G_MY * L + l] += gmy
                                buf[G_A * L + l] += g_s * half * dx * dx
                                buf[G_B * L + l] += g_s * dx * dy
                                buf[G_C * L + l] += g_s * half * dy * dy
                                buf[G_O * L + l] += g_alpha_j * e if free else zero
                                buf[G_R * L + l] += w * gr
                                buf[G_G * L + l] += w * ggr
                                buf[G_BL * L + l] += w * gb
                                buf[G_Z * L + l] += w * gd
                                buf[G_ABS_MX * L + l] += abs(gmx)
                                buf[G_ABS_MY * L + l] += abs(gmy)
                                okl[l] = one_i if ok else zero_i
                            for l in range(L):            # kept out of the lane loop: a reduction
                                n_ok += okl[l]            # there would halve its vector width
                    if n_ok > 0:
                        _lane_sums_into(buf, grads, p, g)
                        contributions[p] += n_ok


composite_backward, composite_backward_serial = parallel_and_serial(_composite_backward)


def backward_kernel(dtype):
    """The backward compositor for an image dtype (parallel float32, serial float64)."""
    return composite_backward if np.dtype(dtype) == np.float32 else composite_backward_serial
