"""Numba front-to-back alpha compositing over 16x16 tiles, forward and exact backward.

Layout, chosen for a 2-core CPU (see docs/rasterizer.md for the measurements behind it):

* Per-Gaussian inputs are packed into one 16-float row (one cache line), visible Gaussians
  only and nearest first, so a tile's list (ascending row ids) walks memory forwards.
* Tiles are dealt round-robin, heaviest first, to ``n_chunks`` work groups (one prange
  iteration each) so both cores get a fair share; each group owns its scratch buffers.
* A tile is 16 sub-blocks of 4x4 pixels whose 16 pixels are SIMD lanes (a branch-free lane
  loop the compiler vectorises). Each Gaussian of the tile list visits only the sub-blocks
  its exact bounding box of {sigma <= ln(255 o) + margin} reaches, and only those with a
  live pixel; the tile stops once every pixel has stopped.
* The backward walks the tile list back to front from the last contributor, recovering T
  by division, accumulates each Gaussian's lane gradients over its sub-blocks, sums the 16
  lanes with a fixed pairwise tree (deterministic) and adds the result into a per-group
  buffer (no races); groups are summed afterwards.

Dtype-generic (float32 for speed, float64 for gradcheck): constants come in through
``consts`` in the image dtype so float32 math never silently widens to float64.
"""

from __future__ import annotations

import types

import numpy as np
from numba import njit, prange

from nuav2.splat._fastexp import exp_neg_lanes
from nuav2.splat.constants import ALPHA_MAX, ALPHA_MIN, SIGMA_REJECT_MARGIN, T_STOP, TILE

# slots of the consts vector
_HALF, _ONE, _ZERO, _AMIN, _AMAX, _TSTOP = range(6)
# columns of the packed per-Gaussian rows
P_MX, P_MY, P_A, P_B, P_C, P_O, P_THR, P_R, P_G, P_BL, P_Z, P_EX, P_EY = range(13)
N_PACKED = 13
PACKED_WIDTH = 16
# channels of the per-Gaussian gradient buffer
G_MX, G_MY, G_A, G_B, G_C, G_O, G_R, G_G, G_BL, G_Z, G_ABS_MX, G_ABS_MY = range(12)
N_GRAD = 12

SUB = 4                          # sub-block side in pixels; a sub-block's pixels are the SIMD lanes
SUBS_PER_SIDE = TILE // SUB
N_SUBS = SUBS_PER_SIDE * SUBS_PER_SIDE
LANES = SUB * SUB


def make_consts(dtype) -> np.ndarray:
    return np.array([0.5, 1.0, 0.0, ALPHA_MIN, ALPHA_MAX, T_STOP], dtype=dtype)


def _pack_impl(means2d, conics, opacities, colors, depths, order, packed):
    for k in prange(order.shape[0]):
        g = order[k]
        a = np.float64(conics[g, 0])
        b = np.float64(conics[g, 1])
        c = np.float64(conics[g, 2])
        o = np.float64(opacities[g])
        thr = np.log(255.0 * o) + SIGMA_REJECT_MARGIN if o > 0.0 else -1.0
        det = a * c - b * b
        ex = np.inf
        ey = np.inf
        if det > 0.0 and thr > 0.0 and np.isfinite(det):
            ex = np.sqrt(max(2.0 * thr * c, 0.0) / det)
            ey = np.sqrt(max(2.0 * thr * a, 0.0) / det)
        packed[k, P_MX] = means2d[g, 0]
        packed[k, P_MY] = means2d[g, 1]
        packed[k, P_A] = conics[g, 0]
        packed[k, P_B] = conics[g, 1]
        packed[k, P_C] = conics[g, 2]
        packed[k, P_O] = opacities[g]
        packed[k, P_THR] = thr if np.isfinite(thr) else -1.0
        packed[k, P_R] = colors[g, 0]
        packed[k, P_G] = colors[g, 1]
        packed[k, P_BL] = colors[g, 2]
        packed[k, P_Z] = depths[g]
        packed[k, P_EX] = ex if ex < 1e30 else np.inf
        packed[k, P_EY] = ey if ey < 1e30 else np.inf


def pack_gaussians(means2d: np.ndarray, conics: np.ndarray, opacities: np.ndarray, colors: np.ndarray,
                   depths: np.ndarray, order: np.ndarray) -> np.ndarray:
    """(len(order), 16) rows for Gaussians ``order`` (visible, nearest first): mean, conic,
    opacity, reject threshold, colour, depth, ellipse half-extents.

    The threshold is ln(255 o) + margin: exponents above it give alpha < 1/255 in any precision.
    The half-extents bound {sigma <= threshold}: e_x = sqrt(2 thr cov_xx) with cov = conic^-1
    (inf when the float conic is degenerate: the Gaussian is then tested against every pixel).
    """
    packed = np.zeros((len(order), PACKED_WIDTH), means2d.dtype)
    pack = _pack if means2d.dtype == np.float32 else _pack_serial
    pack(means2d, conics, opacities, colors, depths, order, packed)
    return packed


@njit(cache=True, inline="always")
def _sub_range(m, e, base):
    """Sub-block index range [lo, hi] of local pixels i (centre base + i + 0.5) with |centre - m| <= e."""
    if not (e < 1e30):
        return 0, SUBS_PER_SIDE - 1
    lo = np.ceil(np.float64(m) - np.float64(e) - 0.5 - base)
    hi = np.floor(np.float64(m) + np.float64(e) - 0.5 - base)
    if hi < 0.0 or lo > TILE - 1.0:
        return 1, 0
    return int(max(lo, 0.0)) // SUB, int(min(hi, TILE - 1.0)) // SUB


@njit(cache=True, inline="always")
def _row_data(packed, g):
    return (packed[g, P_MX], packed[g, P_MY], packed[g, P_A], packed[g, P_B], packed[g, P_C], packed[g, P_O],
            packed[g, P_THR], packed[g, P_R], packed[g, P_G], packed[g, P_BL], packed[g, P_Z])


def composite_forward(packed, offsets, ids, tile_order, px_centres, py_centres, n_chunks, consts,
                      out_color, out_depth, out_T, out_last):
    """Fill premultiplied colour (H,W,3), depth sum (H,W), final T (H,W) and the last contributor
    (H,W; index in the tile's list, -1 for none)."""
    height, width = out_T.shape
    tiles_x = (width + TILE - 1) // TILE
    n_tiles = tile_order.shape[0]
    half = consts[_HALF]
    one = consts[_ONE]
    zero = consts[_ZERO]
    amin = consts[_AMIN]
    amax = consts[_AMAX]
    tstop = consts[_TSTOP]
    dt = out_T.dtype
    L = LANES
    NS = 7 * L            # lane state per sub-block: px, py, T, r, g, b, depth
    for p in prange(n_chunks):
        st = np.empty(N_SUBS * NS, dt)
        last = np.empty(N_SUBS * L, np.int32)
        alive = np.empty(N_SUBS * L, np.int32)
        sub_alive = np.empty(N_SUBS, np.int64)
        for k in range(p, n_tiles, n_chunks):
            t = tile_order[k]
            ty = t // tiles_x
            tx = t - ty * tiles_x
            start = offsets[t]
            n = offsets[t + 1] - start
            live_subs = 0
            for sb in range(N_SUBS):
                iy0 = ty * TILE + (sb // SUBS_PER_SIDE) * SUB
                ix0 = tx * TILE + (sb % SUBS_PER_SIDE) * SUB
                base = sb * NS
                cnt = 0
                for l in range(L):
                    ix = ix0 + l % SUB
                    iy = iy0 + l // SUB
                    st[base + l] = px_centres[min(ix, width - 1)]
                    st[base + L + l] = py_centres[min(iy, height - 1)]
                    st[base + 2 * L + l] = one
                    st[base + 3 * L + l] = zero
                    st[base + 4 * L + l] = zero
                    st[base + 5 * L + l] = zero
                    st[base + 6 * L + l] = zero
                    last[sb * L + l] = -1
                    inside = 1 if (ix < width and iy < height) else 0
                    alive[sb * L + l] = inside
                    cnt += inside
                sub_alive[sb] = cnt
                live_subs += 1 if cnt > 0 else 0
            for j in range(n):
                if live_subs == 0:
                    break
                g = ids[start + j]
                mx, my, a, b, c, o, thr, cr, cg, cb, z = _row_data(packed, g)
                bx0, bx1 = _sub_range(mx, packed[g, P_EX], tx * TILE)
                by0, by1 = _sub_range(my, packed[g, P_EY], ty * TILE)
                jj = np.int32(j)
                for by in range(by0, by1 + 1):
                    for bx in range(bx0, bx1 + 1):
                        sb = by * SUBS_PER_SIDE + bx
                        if sub_alive[sb] == 0:
                            continue
                        sst = st[sb * NS:(sb + 1) * NS]
                        slast = last[sb * L:(sb + 1) * L]
                        salive = alive[sb * L:(sb + 1) * L]
                        n_alive = 0
                        for l in range(L):
                            dx = mx - sst[l]
                            dy = my - sst[L + l]
                            s = half * (a * dx * dx + c * dy * dy) + b * dx * dy
                            ok = (s >= zero) and (s <= thr) and (salive[l] != 0)
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
                            slast[l] = jj if use else slast[l]
                            still = 0 if stop else salive[l]
                            salive[l] = still
                            n_alive += still
                        sub_alive[sb] = n_alive
                        if n_alive == 0:
                            live_subs -= 1
            for sb in range(N_SUBS):
                iy0 = ty * TILE + (sb // SUBS_PER_SIDE) * SUB
                ix0 = tx * TILE + (sb % SUBS_PER_SIDE) * SUB
                base = sb * NS
                for l in range(L):
                    ix = ix0 + l % SUB
                    iy = iy0 + l // SUB
                    if ix < width and iy < height:
                        out_color[iy, ix, 0] = st[base + 3 * L + l]
                        out_color[iy, ix, 1] = st[base + 4 * L + l]
                        out_color[iy, ix, 2] = st[base + 5 * L + l]
                        out_depth[iy, ix] = st[base + 6 * L + l]
                        out_T[iy, ix] = st[base + 2 * L + l]
                        out_last[iy, ix] = last[sb * L + l]


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


def composite_backward(packed, offsets, ids, tile_order, px_centres, py_centres, n_chunks, consts,
                       out_T, out_last, g_color, g_depth, g_alpha, grads):
    """Add dL/d(per-Gaussian inputs) into grads (n_chunks, N, 12) given dL/d(outputs)."""
    height, width = out_T.shape
    tiles_x = (width + TILE - 1) // TILE
    n_tiles = tile_order.shape[0]
    half = consts[_HALF]
    one = consts[_ONE]
    zero = consts[_ZERO]
    amin = consts[_AMIN]
    amax = consts[_AMAX]
    dt = out_T.dtype
    L = LANES
    # lane state per sub-block: px, py, T, S_r, S_g, S_b, S_depth, dL/dr, dL/dg, dL/db, dL/ddepth,
    # dL/dalpha * T_final (S = colour/depth accumulated behind the current Gaussian)
    NS = 12 * L
    for p in prange(n_chunks):
        st = np.empty(N_SUBS * NS, dt)
        last = np.empty(N_SUBS * L, np.int32)
        sub_hi = np.empty(N_SUBS, np.int64)
        buf = np.empty(N_GRAD * L, dt)
        for k in range(p, n_tiles, n_chunks):
            t = tile_order[k]
            ty = t // tiles_x
            tx = t - ty * tiles_x
            start = offsets[t]
            j_hi = -1
            for sb in range(N_SUBS):
                iy0 = ty * TILE + (sb // SUBS_PER_SIDE) * SUB
                ix0 = tx * TILE + (sb % SUBS_PER_SIDE) * SUB
                base = sb * NS
                hi = -1
                for l in range(L):
                    inside = ix0 + l % SUB < width and iy0 + l // SUB < height
                    ix = min(ix0 + l % SUB, width - 1)
                    iy = min(iy0 + l // SUB, height - 1)
                    T_final = out_T[iy, ix]
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
                    lst = out_last[iy, ix] if inside else -1
                    last[sb * L + l] = lst
                    hi = max(hi, lst)
                sub_hi[sb] = hi
                j_hi = max(j_hi, hi)
            for j in range(j_hi, -1, -1):
                g = ids[start + j]
                mx, my, a, b, c, o, thr, cr, cg, cb, z = _row_data(packed, g)
                bx0, bx1 = _sub_range(mx, packed[g, P_EX], tx * TILE)
                by0, by1 = _sub_range(my, packed[g, P_EY], ty * TILE)
                jj = np.int32(j)
                n_ok = 0
                buf[:] = zero
                for by in range(by0, by1 + 1):
                    for bx in range(bx0, bx1 + 1):
                        sb = by * SUBS_PER_SIDE + bx
                        if j > sub_hi[sb]:
                            continue
                        sst = st[sb * NS:(sb + 1) * NS]
                        slast = last[sb * L:(sb + 1) * L]
                        for l in range(L):
                            dx = mx - sst[l]
                            dy = my - sst[L + l]
                            s = half * (a * dx * dx + c * dy * dy) + b * dx * dy
                            ok = (s >= zero) and (s <= thr) and (jj <= slast[l])
                            e = exp_neg_lanes(s if ok else zero)
                            raw = o * e
                            alpha = min(amax, raw)
                            ok = ok and (alpha >= amin)
                            inv_one_m = one / (one - alpha)
                            T = sst[2 * L + l] * inv_one_m if ok else sst[2 * L + l]
                            sst[2 * L + l] = T
                            w = alpha * T if ok else zero
                            gr = sst[7 * L + l]
                            gg = sst[8 * L + l]
                            gb = sst[9 * L + l]
                            gd = sst[10 * L + l]
                            g_alpha_j = (T * (cr * gr + cg * gg + cb * gb + z * gd)
                                         - (sst[3 * L + l] * gr + sst[4 * L + l] * gg
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
                            buf[G_G * L + l] += w * gg
                            buf[G_BL * L + l] += w * gb
                            buf[G_Z * L + l] += w * gd
                            buf[G_ABS_MX * L + l] += abs(gmx)
                            buf[G_ABS_MY * L + l] += abs(gmy)
                            n_ok += 1 if ok else 0
                if n_ok > 0:
                    _lane_sums_into(buf, grads, p, g)


def _unpack_grads_impl(grads, order, out):
    """out[ch, order[k]] = sum_p grads[p, k, ch]: per-group sums back to the caller's Gaussian
    order, channel-major so each parameter's gradient is one contiguous block."""
    for k in prange(order.shape[0]):
        g = order[k]
        for ch in range(N_GRAD):
            acc = grads[0, k, ch]
            for p in range(1, grads.shape[0]):
                acc += grads[p, k, ch]
            out[ch, g] = acc


def _parallel_and_serial(impl):
    """A parallel dispatcher (float32 training path) and a serial twin of the same code, compiled
    in half the time, for the float64 path that only gradcheck and tests use."""
    twin = types.FunctionType(impl.__code__, impl.__globals__, impl.__name__ + "_serial",
                              impl.__defaults__, impl.__closure__)
    twin.__qualname__ = impl.__qualname__ + "_serial"
    return njit(parallel=True, cache=True, nogil=True)(impl), njit(cache=True, nogil=True)(twin)


composite_forward, composite_forward_serial = _parallel_and_serial(composite_forward)
_pack, _pack_serial = _parallel_and_serial(_pack_impl)
composite_backward, composite_backward_serial = _parallel_and_serial(composite_backward)
_unpack_grads, _unpack_grads_serial = _parallel_and_serial(_unpack_grads_impl)


def unpack_grads(grads: np.ndarray, order: np.ndarray, n: int) -> np.ndarray:
    """(N_GRAD, n) per-Gaussian gradients (zeros for culled ones) from the per-group buffer."""
    out = np.zeros((N_GRAD, n), grads.dtype)
    (_unpack_grads if grads.dtype == np.float32 else _unpack_grads_serial)(grads, order, out)
    return out


def kernels_for(dtype) -> tuple:
    """(forward, backward) compositing kernels for an image dtype."""
    if np.dtype(dtype) == np.float32:
        return composite_forward, composite_backward
    return composite_forward_serial, composite_backward_serial


def pixel_centres(size: int, dtype) -> np.ndarray:
    """Pixel centre coordinates j + 0.5 in the image dtype."""
    return (np.arange(size, dtype=np.float64) + 0.5).astype(dtype)


def tile_work_order(offsets: np.ndarray) -> np.ndarray:
    """Tiles, heaviest first (dealt round-robin to the work groups for balance)."""
    return np.argsort(-np.diff(offsets), kind="stable").astype(np.int64)
