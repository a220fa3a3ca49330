"""torch.autograd.Function wrappers around the numba kernels (CPU tensors only).

Two functions so that the projected 2D means are a real node of the autograd graph: a
densification strategy can ``retain_grad()`` them, as with gsplat.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass

import numba
import numpy as np
import torch

from nuav2.splat import _backward, _binning, _composite, _forward, _project
from nuav2.splat._stages import count, stage
from nuav2.threads import numba_threads


def _np(t: torch.Tensor | None, shape: tuple[int, ...] = (), dtype=None) -> np.ndarray:
    """A C-contiguous numpy view (or converted copy) of ``t``; zeros of ``shape`` for a missing gradient."""
    if t is None:
        return np.zeros(shape, dtype)
    a = t.detach().contiguous().numpy()
    return a if dtype is None else a.astype(dtype, copy=False)


# Below this many work items (Gaussians x cameras, or pixels + visible Gaussians) a kernel runs
# on one thread: waking the other one costs more than it saves, and on a busy machine a
# descheduled worker can stall a tiny launch for a whole scheduler tick.
SMALL_WORK = 16_384


@contextlib.contextmanager
def threads_for(work: int):
    """Run the enclosed numba launches on one thread when ``work`` is small."""
    if work >= SMALL_WORK or numba.get_num_threads() == 1:
        yield
        return
    with numba_threads(1):
        yield


# The backward pass sums each Gaussian's gradient in one buffer per work group, then adds the buffers
# in order: a number of groups set by the frame (not one per thread) makes the sums, and so a
# reconstruction's bytes, the same on one thread as on two, and on any machine. (Two, one below
# SMALL_WORK: the groups of the two-thread runs measured before this rule.)
BACKWARD_GROUPS = 2


def n_chunks() -> int:
    """Work groups per kernel launch: one per numba thread."""
    return max(1, numba.get_num_threads())


class ProjectFn(torch.autograd.Function):
    """(means, quats, log_scales) -> means2d (C,N,2), conics (C,N,3), depths (C,N), radii (C,N,2) int32."""

    @staticmethod
    def forward(ctx, means, quats, log_scales, opacities, cam_T_world, Ks, width, height, near, far,
                radius_clip):
        m, q, s, o = (_np(t) for t in (means, quats, log_scales, opacities))
        means2d, conics, depths, radii = _project.empty_projection(len(cam_T_world), len(m), m.dtype)
        with threads_for(len(m) * len(cam_T_world)), stage("projection_fwd"):
            _project.project_forward(m, q, s, o, cam_T_world, Ks, float(width), float(height), float(near),
                                     float(far), float(radius_clip), means2d, conics, depths, radii)
        ctx.arrays = (m, q, s, cam_T_world, Ks, float(width), float(height), radii)
        radii_t = torch.from_numpy(radii)
        ctx.mark_non_differentiable(radii_t)
        return torch.from_numpy(means2d), torch.from_numpy(conics), torch.from_numpy(depths), radii_t

    @staticmethod
    def backward(ctx, g_means2d, g_conics, g_depths, _g_radii):
        m, q, s, cam_T_world, Ks, width, height, radii = ctx.arrays
        n_cams, n = radii.shape[:2]
        gm2 = _np(g_means2d, (n_cams, n, 2), m.dtype)
        gc = _np(g_conics, (n_cams, n, 3), m.dtype)
        gd = _np(g_depths, (n_cams, n), m.dtype)
        g_means = np.empty_like(m)
        g_quats = np.empty_like(q)
        g_scales = np.empty_like(s)
        with threads_for(len(m) * n_cams), stage("projection_bwd"):
            _project.project_backward(m, q, s, cam_T_world, Ks, width, height, radii, gm2, gc, gd,
                                      g_means, g_quats, g_scales)
        return (torch.from_numpy(g_means), torch.from_numpy(g_quats), torch.from_numpy(g_scales),
                None, None, None, None, None, None, None, None)


class CompositeFn(torch.autograd.Function):
    """One camera: (means2d, conics, opacities, colors, depths) -> colour sum, depth sum, alpha."""

    @staticmethod
    def forward(ctx, means2d, conics, opacities, colors, depths, radii, width, height, absgrad_out):
        dt_np = np.float32 if means2d.dtype == torch.float32 else np.float64
        m2, con, op, col, dep = (_np(t, dtype=dt_np) for t in (means2d, conics, opacities, colors, depths))
        frame = composite_forward(m2, con, op, col, dep, radii, int(width), int(height))
        ctx.frame = frame
        ctx.n = len(m2)
        ctx.absgrad_out = absgrad_out
        return (torch.from_numpy(frame.color), torch.from_numpy(frame.depth),
                torch.from_numpy(1.0 - frame.T))

    @staticmethod
    def backward(ctx, g_color, g_depth, g_alpha):
        frame = ctx.frame
        T = frame.T
        gcol = _np(g_color, T.shape + (3,), T.dtype)
        gdep = _np(g_depth, T.shape, T.dtype)
        galp = _np(g_alpha, T.shape, T.dtype)
        absgrad = np.zeros((ctx.n, 2), T.dtype) if ctx.absgrad_out is None else ctx.absgrad_out.numpy()
        grads = composite_backward(frame, gcol, gdep, galp, ctx.n, absgrad)
        return tuple(torch.from_numpy(g) for g in grads) + (None, None, None, None)


@dataclass
class Frame:
    """What one camera's forward leaves for its backward."""

    packed: np.ndarray          # (rows, 16) visible Gaussians nearest first (rows of binned slabs filled)
    order: np.ndarray           # row -> Gaussian id
    slab_offsets: np.ndarray    # (n_slabs, n_tiles + 1) into ids
    ids: np.ndarray             # rows per tile per slab
    color: np.ndarray           # (H, W, 3) colour sum
    depth: np.ndarray           # (H, W) depth sum
    T: np.ndarray               # (H, W) final transmittance
    last: np.ndarray            # (H, W) last contributing row, -1 for none
    work: int                   # pixels + visible Gaussians (thread heuristic)


def composite_forward(m2: np.ndarray, con: np.ndarray, op: np.ndarray, col: np.ndarray, dep: np.ndarray,
                      radii: np.ndarray, width: int, height: int) -> Frame:
    """Depth sort, then per depth slab (nearest first): pack its rows, bin them into the tiles that
    still have a live pixel, composite; stop once every pixel has stopped."""
    dt = m2.dtype
    with stage("sort"):
        order = _binning.depth_order(dep, radii)
    work = len(order) + width * height
    with threads_for(work):
        groups = n_chunks()
        with stage("pack"):
            packed = np.empty((len(order), _composite.PACKED_WIDTH), dt)
            color = np.zeros((height, width, 3), dt)
            depth = np.zeros((height, width), dt)
            T = np.ones((height, width), dt)
            last = np.full((height, width), -1, np.int32)
            done = np.zeros((height, width), np.uint8)
            px = _composite.pixel_centres(width, dt)
            py = _composite.pixel_centres(height, dt)
            consts = _composite.make_consts(dt)
        n_tiles = _binning.n_tiles(width, height)
        tile_alive = np.ones(n_tiles, np.uint8)
        bounds = _binning.slab_bounds(len(packed))
        offsets_per_slab, ids_per_slab, base = [], [], 0
        kernel = _forward.slab_kernel(dt)
        for lo, hi in zip(bounds[:-1], bounds[1:]):
            with stage("pack"):
                _composite.pack_rows(m2, con, op, col, dep, order, packed, lo, hi)
            with stage("binning"):
                offsets, ids = _binning.bin_slab(packed, lo, hi, width, height, tile_alive, groups)
                counts = np.diff(offsets)
                tiles = _composite.heaviest_first(counts)[:np.count_nonzero(counts)]
            with stage("composite_fwd"):
                kernel(packed, offsets, ids, tiles, px, py, groups, consts, color, depth, T, last, done,
                       tile_alive)
            offsets_per_slab.append(offsets + base)
            ids_per_slab.append(ids)
            base += len(ids)
            if not tile_alive.any():
                break
    slab_offsets = (np.stack(offsets_per_slab) if offsets_per_slab
                    else np.zeros((1, n_tiles + 1), np.int64))
    ids = np.concatenate(ids_per_slab) if ids_per_slab else np.zeros(0, np.int32)
    count("tile_pairs", len(ids))
    count("depth_slabs", len(offsets_per_slab))
    return Frame(packed, order, slab_offsets, ids, color, depth, T, last, work)


def composite_backward(frame: Frame, gcol: np.ndarray, gdep: np.ndarray, galp: np.ndarray, n: int,
                       absgrad: np.ndarray) -> tuple[np.ndarray, ...]:
    """Gradients w.r.t. means2d, conics, opacities, colours and depths of the n Gaussians, in the
    caller's order; |dL/dmeans2d| summed over pixels is added into absgrad (n, 2).

    Only rows up to the furthest last contributor can receive gradient, so the per-group
    buffers and their reduction stop there (behind an opaque foreground that is a short prefix).
    """
    dt = frame.T.dtype
    height, width = frame.T.shape
    rows = int(frame.last.max(initial=-1)) + 1
    with threads_for(frame.work):
        groups = BACKWARD_GROUPS if frame.work >= SMALL_WORK else 1
        with stage("composite_bwd"):
            per_tile = (frame.slab_offsets[:, 1:] - frame.slab_offsets[:, :-1]).sum(0)
            tiles = _composite.heaviest_first(per_tile)[:np.count_nonzero(per_tile)]
            grads = np.zeros((groups, rows, _composite.N_GRAD), dt)
            contributions = np.zeros(groups, np.int64)
            _backward.backward_kernel(dt)(
                frame.packed, frame.slab_offsets, frame.ids, tiles, _composite.pixel_centres(width, dt),
                _composite.pixel_centres(height, dt), groups, _composite.make_consts(dt), frame.T, frame.last,
                gcol, gdep, galp, grads, contributions)
        count("contributions", int(contributions.sum()))
        with stage("unpack"):
            return _composite.unpack_grads(grads, frame.order[:rows], n, absgrad)
