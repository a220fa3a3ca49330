"""gsplat's own PyTorch rendering path (``gsplat.rendering._rasterization``) run on the CPU.

gsplat (>= 1.5) ships a pure-torch rasterization for testing, but three of its pieces need
CUDA or another package. This module supplies them, written here from their documented
semantics, and runs gsplat's own code for everything else (projection, covariance, SH,
tile offsets, the batched front-to-back loop, alpha, background, expected depth):

* ``isect_tiles``: tile-Gaussian intersections from each Gaussian's pixel radius square,
  vectorised (gsplat's torch version is a Python loop over Gaussians and tiles);
* ``rasterize_to_indices_in_range``: the (Gaussian, pixel) pairs that contribute to each
  pixel, front to back, with the CUDA kernel's rules (skip sigma < 0 or alpha < 1/255,
  stop before T drops to 1e-4, start from the given transmittance), vectorised over pixels;
* nerfacc's ``render_weight_from_alpha`` / ``accumulate_along_rays``: the per-ray exclusive
  product of (1 - alpha) and the per-ray weighted sums, differentiable.

It is the real peer reference for ``nuav2 bench raster`` and the CPU parity test; it needs
``gsplat`` installed (the ``dev`` extra) but no GPU, and is slow and memory-hungry.
"""

from __future__ import annotations

import contextlib
import importlib.util
import math
import sys
import types

import numpy as np
import torch

from nuav2.splat.constants import ALPHA_MAX, ALPHA_MIN, EPS2D, T_STOP

PIXEL_CHUNK_ELEMENTS = 8_000_000     # pixels x list positions evaluated at once in the indices port
_max_isects: int | None = None       # set by rasterize_gsplat_torch for the duration of a call
# gsplat's torch loop visits each tile list in steps of batch_per_iter x 256 entries and forgets
# between steps which pixels stopped, so with its default (100) a pixel whose list is longer
# than 25,600 resumes after T fell to 1e-4 (up to 1e-4 of colour per step); one step covering
# every list keeps the stop rule of gsplat's CUDA kernels, which is what the comparison is about
ONE_STEP = 1 << 40


class ReferenceTooLarge(RuntimeError):
    """gsplat's intersections would exceed the caller's budget (its torch path holds them all)."""


def gsplat_installed() -> bool:
    return importlib.util.find_spec("gsplat") is not None


@torch.no_grad()
def isect_tiles(means2d, radii, depths, tile_size, tile_width, tile_height, sort=True, segmented=False,
                packed=False, n_images=None, image_ids=None, gaussian_ids=None):
    """Intersections as gsplat's ``isect_tiles`` (non-packed): ids (image << (tile_bits + 32)) |
    (tile << 32) | depth bits, sorted; flatten ids image * N + Gaussian."""
    if packed:
        raise NotImplementedError("packed mode is not supported by the CPU glue")
    image_dims = means2d.shape[:-2]
    n = means2d.shape[-2]
    n_img = math.prod(image_dims)
    m2 = means2d.reshape(n_img, n, 2)
    rad = radii.reshape(n_img, n, 2)
    lo = torch.floor(m2 / tile_size - rad / tile_size).int()
    hi = torch.ceil(m2 / tile_size + rad / tile_size).int()
    lo[..., 0].clamp_(0, tile_width)
    lo[..., 1].clamp_(0, tile_height)
    hi[..., 0].clamp_(0, tile_width)
    hi[..., 1].clamp_(0, tile_height)
    span = hi - lo
    per_gauss = span.prod(-1) * (rad > 0).all(-1)
    flat = per_gauss.flatten().long()
    total = int(flat.sum())
    if _max_isects is not None and total > _max_isects:
        raise ReferenceTooLarge(f"gsplat's torch path needs {total:,} tile-Gaussian pairs "
                                f"(budget {_max_isects:,}); skipped")
    index = torch.repeat_interleave(torch.arange(n_img * n), flat)            # image * N + Gaussian
    local = torch.arange(len(index)) - torch.repeat_interleave(torch.cumsum(flat, 0) - flat, flat)
    w = span[..., 0].reshape(-1).long()[index]
    tx = lo[..., 0].reshape(-1).long()[index] + local % w
    ty = lo[..., 1].reshape(-1).long()[index] + local // w
    tile_bits = (tile_width * tile_height).bit_length()
    depth_bits = torch.from_numpy(
        depths.detach().reshape(-1).float().numpy().view(np.int32).astype(np.int64) & 0xFFFFFFFF)[index]
    image = index // n
    isect_ids = (image << (tile_bits + 32)) | ((ty * tile_width + tx) << 32) | depth_bits
    flatten_ids = index.int()
    if sort:
        isect_ids, perm = torch.sort(isect_ids, stable=True)
        flatten_ids = flatten_ids[perm]
    return per_gauss.reshape(image_dims + (n,)).int(), isect_ids, flatten_ids


@torch.no_grad()
def rasterize_to_indices_in_range(range_start, range_end, transmittances, means2d, conics, opacities,
                                  image_width, image_height, tile_size, isect_offsets, flatten_ids):
    """Contributing (Gaussian, pixel, image) ids for list batches [range_start, range_end) of each
    tile (a batch is tile_size^2 list entries), pixel-major and front to back per pixel."""
    image_dims = means2d.shape[:-2]
    n = means2d.shape[-2]
    n_img = math.prod(image_dims)
    tiles_h, tiles_w = isect_offsets.shape[-2:]
    dt = means2d.dtype
    m2 = means2d.reshape(n_img * n, 2)
    con = conics.reshape(n_img * n, 3)
    opa = opacities.reshape(n_img * n)
    starts = isect_offsets.reshape(-1).long()
    ends = torch.cat([starts[1:], torch.tensor([len(flatten_ids)])])
    block = tile_size * tile_size
    # every inside pixel with its (image, tile)
    img, py, px = torch.meshgrid(torch.arange(n_img), torch.arange(image_height), torch.arange(image_width),
                                 indexing="ij")
    img, py, px = img.reshape(-1), py.reshape(-1), px.reshape(-1)
    tile = img * (tiles_h * tiles_w) + (py // tile_size) * tiles_w + px // tile_size
    first = starts[tile] + block * range_start
    stop_at = torch.minimum(ends[tile], starts[tile] + block * range_end)
    live = torch.nonzero(first < stop_at).flatten()
    trans = transmittances.reshape(-1).to(dt)[live].clone()
    pos = first[live]
    cx = px[live].to(dt) + 0.5
    cy = py[live].to(dt) + 0.5
    out_pix, out_gauss, out_key = [], [], []
    while len(live):
        width = max(1, min(block, PIXEL_CHUNK_ELEMENTS // len(live)))
        cols = pos[:, None] + torch.arange(width)
        in_list = cols < stop_at[live][:, None]
        g = flatten_ids[cols.clamp_max(len(flatten_ids) - 1)].long()
        dx = m2[g, 0] - cx[:, None]
        dy = m2[g, 1] - cy[:, None]
        c = con[g]
        sigma = 0.5 * (c[..., 0] * dx * dx + c[..., 2] * dy * dy) + c[..., 1] * dx * dy
        alpha = torch.clamp_max(opa[g] * torch.exp(-sigma), ALPHA_MAX)
        valid = in_list & (sigma >= 0) & (alpha >= ALPHA_MIN)
        factor = torch.where(valid, 1.0 - alpha, torch.ones_like(alpha))
        # T after each entry, multiplied in the kernel's order: ((T f1) f2) f3 ...
        after = torch.cumprod(torch.cat([trans[:, None], factor], 1), 1)[:, 1:]
        used = valid & (after > T_STOP)
        stopped = (valid & (after <= T_STOP)).any(1)
        rows, k = torch.nonzero(used, as_tuple=True)
        out_pix.append(live[rows])
        out_gauss.append(g[rows, k])
        out_key.append(cols[rows, k])
        trans = torch.where(used, after, torch.full_like(after, math.inf)).amin(1).clamp_max(trans)
        pos = pos + width
        keep = ~stopped & (pos < stop_at[live])
        live, trans, pos, cx, cy = live[keep], trans[keep], pos[keep], cx[keep], cy[keep]
    pix = torch.cat(out_pix) if out_pix else torch.zeros(0, dtype=torch.long)
    gauss = torch.cat(out_gauss) if out_gauss else torch.zeros(0, dtype=torch.long)
    key = torch.cat(out_key) if out_key else torch.zeros(0, dtype=torch.long)
    order = torch.argsort(pix * (int(key.max()) + 1 if len(key) else 1) + key)
    flat_pixel = pix[order]                                  # image * H * W + y * W + x
    hw = image_width * image_height
    return gauss[order] % n, flat_pixel % hw, flat_pixel // hw


def render_weight_from_alpha(alphas, ray_indices=None, n_rays=None, **_unused):
    """(weights, transmittance) with T_i = prod_{j<i on the same ray} (1 - alpha_j); rays are
    contiguous runs of ``ray_indices``. Computed as an exclusive segmented sum of log(1 - alpha)
    in float64 (alpha <= 0.999, so no log of zero)."""
    log_keep = torch.log1p(-alphas.to(torch.float64))
    inclusive = torch.cumsum(log_keep, 0)
    exclusive = inclusive - log_keep
    if len(alphas):
        new_ray = torch.ones_like(ray_indices, dtype=torch.bool)
        new_ray[1:] = ray_indices[1:] != ray_indices[:-1]
        run = torch.cumsum(new_ray.long(), 0) - 1
        exclusive = exclusive - exclusive[new_ray][run]
    trans = torch.exp(exclusive).to(alphas.dtype)
    return alphas * trans, trans


def accumulate_along_rays(weights, values=None, ray_indices=None, n_rays=None):
    """Per-ray sums of weights * values (of weights when values is None), shape (n_rays, D)."""
    src = weights[:, None] if values is None else weights[:, None] * values
    out = torch.zeros(n_rays, src.shape[-1], dtype=src.dtype)
    return out.index_add(0, ray_indices, src)


def _sh(degrees_to_use, dirs, coeffs, masks=None):
    from gsplat.cuda._torch_impl import _spherical_harmonics

    return _spherical_harmonics(degrees_to_use, dirs, coeffs)


@contextlib.contextmanager
def _cpu_glue(max_isects: int | None):
    """Point gsplat's CUDA-only entry points at the CPU pieces above for the enclosed block."""
    global _max_isects
    import gsplat.cuda._torch_impl as torch_impl
    import gsplat.cuda._wrapper as wrapper
    import gsplat.rendering as rendering

    patches = [(rendering, "isect_tiles", isect_tiles),
               (rendering, "isect_offset_encode", torch_impl._isect_offset_encode),
               (rendering, "spherical_harmonics", _sh),
               (wrapper, "rasterize_to_indices_in_range", rasterize_to_indices_in_range)]
    saved = [(mod, name, getattr(mod, name)) for mod, name, _ in patches]
    had_nerfacc = "nerfacc" in sys.modules
    old_nerfacc = sys.modules.get("nerfacc")
    shim = types.ModuleType("nerfacc")
    shim.render_weight_from_alpha = render_weight_from_alpha
    shim.accumulate_along_rays = accumulate_along_rays
    try:
        for mod, name, fn in patches:
            setattr(mod, name, fn)
        sys.modules["nerfacc"] = shim
        _max_isects = max_isects
        yield
    finally:
        _max_isects = None
        for mod, name, fn in saved:
            setattr(mod, name, fn)
        if had_nerfacc:
            sys.modules["nerfacc"] = old_nerfacc
        else:
            sys.modules.pop("nerfacc", None)


def rasterize_gsplat_torch(means, quats, log_scales, opacity_logits, colors, world_T_cam, K, width: int,
                           height: int, *, near: float = 0.01, far: float = 1e10, background=None,
                           sh_degree: int | None = None, eps2d: float = EPS2D,
                           max_isects: int | None = None):
    """gsplat's torch rasterization with nuav2's inputs (raw parameters, world_T_cam poses) on the
    CPU; returns (rgb, alpha, depth) shaped like :func:`nuav2.splat.rasterize` and gsplat's meta.

    The nuav2 conventions are applied here, as a user of gsplat would: quaternions (w, x, y, z),
    scales = exp(log_scales), opacities = sigmoid(logits), viewmats = inverse(world_T_cam).
    Raises :class:`ReferenceTooLarge` when gsplat would hold more than ``max_isects`` pairs.
    """
    from gsplat.rendering import _rasterization

    dtype = means.dtype
    poses = torch.as_tensor(np.asarray(world_T_cam), dtype=torch.float64)
    batched = poses.ndim == 3
    viewmats = torch.linalg.inv(poses.reshape(-1, 4, 4)).to(dtype)
    Ks = torch.as_tensor(np.asarray(K), dtype=dtype).expand(len(viewmats), 3, 3).contiguous()
    bg = None
    if background is not None:
        bg = torch.as_tensor(background, dtype=dtype).expand(len(viewmats), 3)
    if sh_degree is None and colors.ndim == 3:
        sh_degree = math.isqrt(colors.shape[1]) - 1
    with _cpu_glue(max_isects):
        renders, alphas, meta = _rasterization(
            means, quats, torch.exp(log_scales), torch.sigmoid(opacity_logits), colors, viewmats, Ks,
            int(width), int(height), near_plane=near, far_plane=far, eps2d=eps2d, sh_degree=sh_degree,
            backgrounds=bg, render_mode="RGB+ED", rasterize_mode="classic", batch_per_iter=ONE_STEP)
    rgb, alpha, depth = renders[..., :3], alphas[..., 0], renders[..., 3]
    if not batched:
        rgb, alpha, depth = rgb[0], alpha[0], depth[0]
    return rgb, alpha, depth, meta


def rasterize_gsplat_reference(means, quats, log_scales, opacity_logits, colors, cams, width: int,
                               height: int, near: float, far: float, background, sh_degree: int | None,
                               radius_clip: float):
    """The ``backend="gsplat-reference"`` of :func:`nuav2.splat.rasterize`: gsplat's torch path on the CPU
    behind the same input and output conversion as the CUDA backend
    (:func:`nuav2.splat.gsplat_backend.gsplat_inputs` / ``from_gsplat``), so a trainer can run on gsplat's
    output conventions without a GPU.

    Where gsplat's torch path differs from its CUDA kernels: it gives no ``means2d.absgrad`` (autograd's
    ``.grad`` is the same quantity as the CUDA one), and its radii use 3.33 sigma without the opacity-aware
    bound or the opacity cull, so Gaussians fainter than 1/255 and some near the image edge count as
    visible there (with zero gradient). ``radius_clip`` is not supported."""
    from gsplat.rendering import _rasterization

    from nuav2.splat.gsplat_backend import from_gsplat, gsplat_inputs

    if means.is_cuda:
        raise ValueError("backend='gsplat-reference' runs on the CPU; use backend='gsplat' for CUDA tensors")
    if radius_clip > 0:
        raise ValueError("backend='gsplat-reference' does not support radius_clip > 0")
    with _cpu_glue(None):
        renders, alphas, meta = _rasterization(
            **gsplat_inputs(means, quats, log_scales, opacity_logits, colors, cams), width=int(width),
            height=int(height), near_plane=near, far_plane=far, eps2d=EPS2D, sh_degree=sh_degree,
            render_mode="RGB+ED", rasterize_mode="classic", batch_per_iter=ONE_STEP)
    return from_gsplat(renders, alphas, meta, background, cams, "gsplat-reference")
