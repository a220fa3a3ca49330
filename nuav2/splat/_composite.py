"""Shared layout of the compositing kernels: packed per-Gaussian rows, lane blocks, gradient channels.

* Per-Gaussian inputs are packed into one 16-float row (one cache line), visible Gaussians
  only and nearest first, so a tile's list (ascending row ids) walks memory forwards and a
  row id orders like depth.
* A 16x16 tile is 16 sub-blocks of 4x4 pixels whose 16 pixels are SIMD lanes (branch-free
  lane loops the compiler vectorises).
* Per-Gaussian gradients go into a per-work-group buffer (no races) summed afterwards.

The forward kernel lives in :mod:`nuav2.splat._forward`, the backward in
:mod:`nuav2.splat._backward`. Dtype-generic (float32 for speed, float64 for gradcheck):
constants come in through ``consts`` in the image dtype so float32 math never silently
widens to float64.
"""

from __future__ import annotations

import types

import numpy as np
from numba import njit, prange

from nuav2.splat.constants import ALPHA_MAX, ALPHA_MIN, SIGMA_REJECT_MARGIN, T_STOP, TILE

# slots of the consts vector
C_HALF, C_ONE, C_ZERO, C_AMIN, C_AMAX, C_TSTOP = range(6)
# columns of the packed per-Gaussian rows
P_MX, P_MY, P_A, P_B, P_C, P_O, P_THR, P_R, P_G, P_BL, P_Z, P_EX, P_EY = range(13)
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


def parallel_and_serial(impl):
    """A parallel dispatcher (float32 training path) and a serial twin of the same code, compiled
    in half the time, for the float64 path that only gradcheck and tests use."""
    twin = types.FunctionType(impl.__code__, impl.__globals__, impl.__name__ + "_serial",
                              impl.__defaults__, impl.__closure__)
    twin.__qualname__ = impl.__qualname__ + "_serial"
    return njit(parallel=True, cache=True, nogil=True)(impl), njit(cache=True, nogil=True)(twin)


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


_pack, _pack_serial = parallel_and_serial(_pack_impl)


def pack_rows(means2d: np.ndarray, conics: np.ndarray, opacities: np.ndarray, colors: np.ndarray,
              depths: np.ndarray, order: np.ndarray, packed: np.ndarray, lo: int, hi: int) -> None:
    """Fill rows lo..hi-1 of ``packed`` (16 wide) for Gaussians order[lo:hi] (visible, nearest
    first): mean, conic, opacity, reject threshold, colour, depth, ellipse half-extents.

    The threshold is ln(255 o) + margin: exponents above it give alpha < 1/255 in any precision.
    The half-extents bound {sigma <= threshold}: e_x = sqrt(2 thr cov_xx) with cov = conic^-1
    (inf when the float conic is degenerate: the Gaussian is then tested against every pixel).
    """
    pack = _pack if means2d.dtype == np.float32 else _pack_serial
    pack(means2d, conics, opacities, colors, depths, order[lo:hi], packed[lo:hi])


@njit(cache=True, inline="always")
def sub_range(m, e, base):
    """Sub-block index range [lo, hi] of local pixels i (centre base + i + 0.5) with |centre - m| <= e."""
    if not (e < 1e30):
        return 0, SUBS_PER_SIDE - 1
    lo = np.ceil(np.float64(m) - np.float64(e) - 0.5 - base)
    hi = np.floor(np.float64(m) + np.float64(e) - 0.5 - base)
    if hi < 0.0 or lo > TILE - 1.0:
        return 1, 0
    return int(max(lo, 0.0)) // SUB, int(min(hi, TILE - 1.0)) // SUB


@njit(cache=True, inline="always")
def band_x_extent(dy0, dy1, a, b, c, thresh, ex, ey):
    """x-extent [x_lo, x_hi], relative to the mean, of the ellipse {sigma <= thresh} cut by the
    band dy0 <= dy <= dy1 (float64; x_lo > x_hi when they miss; -inf, inf for a degenerate conic).

    The cut is convex, so its x-extent is one interval: the ellipse's left (right) edge x(dy) is
    convex (concave) in dy and extremal at its leftmost (rightmost) point, dy = +-b e_x / c, so
    clamping that dy into the band gives the extent.
    """
    det = a * c - b * b
    if not (ex < 1e30 and det > 0.0 and a > 0.0 and c > 0.0):
        return -np.inf, np.inf
    dy0 = max(dy0, -ey)
    dy1 = min(dy1, ey)
    if dy1 < dy0:
        return 1.0, -1.0
    two_ta = 2.0 * thresh * a
    dy = min(dy1, max(dy0, b * ex / c))                  # leftmost point's dy, clamped to the band
    x_lo = (-b * dy - np.sqrt(max(two_ta - det * dy * dy, 0.0))) / a
    dy = min(dy1, max(dy0, -b * ex / c))                 # rightmost point's dy
    x_hi = (-b * dy + np.sqrt(max(two_ta - det * dy * dy, 0.0))) / a
    return x_lo, x_hi


@njit(cache=True, inline="always")
def row_data(packed, g):
    return (packed[g, P_MX], packed[g, P_MY], packed[g, P_A], packed[g, P_B], packed[g, P_C], packed[g, P_O],
            packed[g, P_THR], packed[g, P_R], packed[g, P_G], packed[g, P_BL], packed[g, P_Z])


@njit(cache=True, inline="always")
def lane_pixel(tx, ty, sb, lane):
    """Image (x, y) of lane ``lane`` of sub-block ``sb`` of tile (tx, ty)."""
    return (tx * TILE + (sb % SUBS_PER_SIDE) * SUB + lane % SUB,
            ty * TILE + (sb // SUBS_PER_SIDE) * SUB + lane // SUB)


@njit(cache=True, inline="always")
def _group_sum(grads, k, ch):
    acc = grads[0, k, ch]
    for p in range(1, grads.shape[0]):
        acc += grads[p, k, ch]
    return acc


def _unpack_grads_impl(grads, order, g_means2d, g_conics, g_opacities, g_colors, g_depths, absgrad):
    """Sum the per-group rows of grads and scatter them back to the caller's Gaussian order, one
    row-major array per input (so autograd gets contiguous tensors) and absgrad added in place."""
    for k in prange(order.shape[0]):
        g = order[k]
        g_means2d[g, 0] = _group_sum(grads, k, G_MX)
        g_means2d[g, 1] = _group_sum(grads, k, G_MY)
        g_conics[g, 0] = _group_sum(grads, k, G_A)
        g_conics[g, 1] = _group_sum(grads, k, G_B)
        g_conics[g, 2] = _group_sum(grads, k, G_C)
        g_opacities[g] = _group_sum(grads, k, G_O)
        g_colors[g, 0] = _group_sum(grads, k, G_R)
        g_colors[g, 1] = _group_sum(grads, k, G_G)
        g_colors[g, 2] = _group_sum(grads, k, G_BL)
        g_depths[g] = _group_sum(grads, k, G_Z)
        absgrad[g, 0] += _group_sum(grads, k, G_ABS_MX)
        absgrad[g, 1] += _group_sum(grads, k, G_ABS_MY)


_unpack_grads, _unpack_grads_serial = parallel_and_serial(_unpack_grads_impl)


def unpack_grads(grads: np.ndarray, order: np.ndarray, n: int, absgrad: np.ndarray) -> tuple[np.ndarray, ...]:
    """Per-Gaussian gradients (zeros for rows without any) w.r.t. means2d (n,2), conics (n,3),
    opacities (n,), colours (n,3), depths (n,) from the per-group buffer; adds |dL/dmeans2d|
    into absgrad (n,2)."""
    dt = grads.dtype
    out = (np.zeros((n, 2), dt), np.zeros((n, 3), dt), np.zeros(n, dt), np.zeros((n, 3), dt), np.zeros(n, dt))
    (_unpack_grads if dt == np.float32 else _unpack_grads_serial)(grads, order, *out, absgrad)
    return out


def pixel_centres(size: int, dtype) -> np.ndarray:
    """Pixel centre coordinates j + 0.5 in the image dtype."""
    return (np.arange(size, dtype=np.float64) + 0.5).astype(dtype)


def heaviest_first(counts: np.ndarray) -> np.ndarray:
    """Indices of ``counts``, largest first (dealt round-robin to the work groups for balance)."""
    return np.argsort(-counts, kind="stable").astype(np.int64)
