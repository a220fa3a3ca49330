"""torch.autograd.Function wrappers around the numba kernels (CPU tensors only).

Two functions so that the projected 2D means are a real node of the autograd graph: a
densification strategy can ``retain_grad()`` them, as with gsplat.
"""

from __future__ import annotations

import contextlib

import numba
import numpy as np
import torch

from nuav2.splat import _binning, _composite, _project


def _np(t: torch.Tensor | None, like: np.ndarray | None = None, dtype=None) -> np.ndarray:
    if t is None:
        assert like is not None
        return np.zeros_like(like, dtype=dtype or like.dtype)
    a = t.detach().contiguous().numpy()
    return a if dtype is None else a.astype(dtype, copy=False)


# Below this many work items (Gaussians x cameras, or pixels + visible Gaussians) a kernel runs
# on one thread: waking the other one costs more than it saves, and on a busy machine a
# descheduled worker can stall a tiny launch for a whole scheduler tick.
SMALL_WORK = 16_384


@contextlib.contextmanager
def threads_for(work: int):
    """Run the enclosed numba launches on one thread when ``work`` is small."""
    n = numba.get_num_threads()
    if work >= SMALL_WORK or n == 1:
        yield
        return
    numba.set_num_threads(1)
    try:
        yield
    finally:
        numba.set_num_threads(n)


def n_chunks() -> int:
    """Work groups per kernel launch: one per numba thread."""
    return max(1, numba.get_num_threads())


class ProjectFn(torch.autograd.Function):
    """(means, quats, log_scales) -> means2d (C,N,2), conics (C,N,3), depths (C,N), radii (C,N,2)."""

    @staticmethod
    def forward(ctx, means, quats, log_scales, opacities, cam_T_world, Ks, width, height, near, far,
                radius_clip):
        m = _np(means, dtype=np.float64)
        q = _np(quats, dtype=np.float64)
        s = _np(log_scales, dtype=np.float64)
        o = _np(opacities, dtype=np.float64)
        means2d, conics, depths, radii = _project.empty_projection(len(cam_T_world), len(m))
        with threads_for(len(m) * len(cam_T_world)):
            _project.project_forward(m, q, s, o, cam_T_world, Ks, float(width), float(height), float(near),
                                     float(far), float(radius_clip), means2d, conics, depths, radii)
        ctx.arrays = (m, q, s, cam_T_world, Ks, float(width), float(height), radii)
        ctx.dtype = means.dtype
        radii_t = torch.from_numpy(radii)
        ctx.mark_non_differentiable(radii_t)
        dt = means.dtype
        return (torch.from_numpy(means2d).to(dt), torch.from_numpy(conics).to(dt),
                torch.from_numpy(depths).to(dt), radii_t)

    @staticmethod
    def backward(ctx, g_means2d, g_conics, g_depths, _g_radii):
        m, q, s, cam_T_world, Ks, width, height, radii = ctx.arrays
        n_cams, n = radii.shape[:2]
        gm2 = _np(g_means2d, np.zeros((n_cams, n, 2)), np.float64)
        gc = _np(g_conics, np.zeros((n_cams, n, 3)), np.float64)
        gd = _np(g_depths, np.zeros((n_cams, n)), np.float64)
        g_means = np.zeros_like(m)
        g_quats = np.zeros_like(q)
        g_scales = np.zeros_like(s)
        with threads_for(len(m) * n_cams):
            _project.project_backward(m, q, s, cam_T_world, Ks, width, height, radii, gm2, gc, gd,
                                      g_means, g_quats, g_scales)
        dt = ctx.dtype
        return (torch.from_numpy(g_means).to(dt), torch.from_numpy(g_quats).to(dt),
                torch.from_numpy(g_scales).to(dt), None, None, None, None, None, None, None, None)


class CompositeFn(torch.autograd.Function):
    """One camera: (means2d, conics, opacities, colors, depths) -> colour sum, depth sum, alpha."""

    @staticmethod
    def forward(ctx, means2d, conics, opacities, colors, depths, radii, width, height, absgrad_out):
        dt_np = np.float32 if means2d.dtype == torch.float32 else np.float64
        arrs = tuple(_np(t, dtype=dt_np) for t in (means2d, conics, opacities, colors, depths))
        m2, con, op, col, dep = arrs
        order = _binning.depth_order(dep, radii)
        work = len(order) + int(width) * int(height)
        with threads_for(work):
            # visible Gaussians nearest first: binning reads rows sequentially and each tile's
            # list walks memory forwards
            packed = _composite.pack_gaussians(m2, con, op, col, dep, order)
            chunks = n_chunks()
            offsets, ids = _binning.bin_packed(packed, width, height, chunks)
            tile_order = _composite.tile_work_order(offsets)
            px = _composite.pixel_centres(int(width), dt_np)
            py = _composite.pixel_centres(int(height), dt_np)
            consts = _composite.make_consts(dt_np)
            color = np.empty((height, width, 3), dt_np)
            depth = np.empty((height, width), dt_np)
            T = np.empty((height, width), dt_np)
            last = np.empty((height, width), np.int32)
            forward_kernel = _composite.kernels_for(dt_np)[0]
            forward_kernel(packed, offsets, ids, tile_order, px, py, chunks, consts, color, depth, T, last)
        ctx.arrays = (packed, order, len(m2), offsets, ids, tile_order, px, py, chunks, consts, T, last)
        ctx.work = work
        ctx.absgrad_out = absgrad_out
        return torch.from_numpy(color), torch.from_numpy(depth), torch.from_numpy(1.0 - T)

    @staticmethod
    def backward(ctx, g_color, g_depth, g_alpha):
        packed, order, n, offsets, ids, tile_order, px, py, chunks, consts, T, last = ctx.arrays
        gcol = _np(g_color, np.zeros(T.shape + (3,), T.dtype), T.dtype)
        gdep = _np(g_depth, T, T.dtype)
        galp = _np(g_alpha, T, T.dtype)
        grads = np.zeros((chunks, len(packed), _composite.N_GRAD), T.dtype)
        with threads_for(ctx.work):
            _composite.kernels_for(T.dtype)[1](packed, offsets, ids, tile_order, px, py, chunks, consts, T,
                                               last, gcol, gdep, galp, grads)
            g = torch.from_numpy(_composite.unpack_grads(grads, order, n))     # (12, N) channel-major
        C = _composite
        if ctx.absgrad_out is not None:
            ctx.absgrad_out += g[C.G_ABS_MX:C.G_ABS_MY + 1].T
        return (g[C.G_MX:C.G_MY + 1].T, g[C.G_A:C.G_C + 1].T, g[C.G_O], g[C.G_R:C.G_BL + 1].T, g[C.G_Z],
                None, None, None, None)
