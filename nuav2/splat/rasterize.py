"""Public Gaussian rasterizer: one call from Gaussian parameters and cameras to RGB, alpha, depth.

Shaped like ``gsplat.rasterization`` but with nuav2 conventions: poses are ``world_T_cam``
(OpenCV camera: x right, y down, z forward), quaternions (w, x, y, z), log-scales and opacity
logits (the raw parameters a trainer optimises). Differentiable w.r.t. all Gaussian
parameters. The CPU backend runs numba kernels (see docs/rasterizer.md); ``backend="auto"``
uses gsplat instead when the tensors live on a CUDA device and gsplat is importable;
``backend="gsplat-reference"`` runs gsplat's own PyTorch path on the CPU behind the same
conversions as the CUDA backend (slow; for checking code that reads gsplat's outputs).
"""

from __future__ import annotations

from typing import NamedTuple

import torch

from nuav2.splat._functions import CompositeFn, ProjectFn
from nuav2.splat._inputs import (
    background_rows,
    camera_colors,
    check_gaussians,
    check_image,
    finite_colors,
    prepare_cameras,
)
from nuav2.splat.constants import ALPHA_FLOOR_DEPTH

BACKENDS = ("auto", "cpu", "gsplat", "gsplat-reference")
_INT32_MAX = 2**31 - 1


class RasterOutput(NamedTuple):
    """Images (H,W,...) for one camera, (C,H,W,...) for a batch; meta always has a leading C.

    meta: ``means2d`` (C,N,2) pixel centres, a graph node (``retain_grad()`` it for
    densification; after backward ``meta["means2d"].absgrad`` holds the per-Gaussian sum of
    absolute pixel gradients), ``radii`` (C,N,2) int32 pixel radii (0 = culled), ``visible``
    (C,N) bool, ``depths`` (C,N) camera z, ``conics`` (C,N,3), ``backend`` name.
    """

    rgb: torch.Tensor
    alpha: torch.Tensor
    depth: torch.Tensor
    meta: dict


def rasterize(
    means: torch.Tensor,
    quats: torch.Tensor,
    log_scales: torch.Tensor,
    opacity_logits: torch.Tensor,
    colors: torch.Tensor,
    world_T_cam,
    K,
    width: int,
    height: int,
    *,
    near: float = 0.01,
    far: float = 1e10,
    background: torch.Tensor | None = None,
    sh_degree: int | None = None,
    radius_clip: float = 0.0,
    backend: str = "auto",
) -> RasterOutput:
    """Render N Gaussians into one camera ((4,4) pose, (3,3) K) or a batch ((C,4,4), (C,3,3) or (3,3)).

    means (N,3) world metres; quats (N,4) wxyz, any norm (zero -> identity); log_scales (N,3);
    opacity_logits (N,) (opacity = sigmoid); colors (N,3) RGB or (N,K,3) SH coefficients
    (view-dependent, colour = max(SH + 0.5, 0)); near/far: camera-z culling planes;
    background (3,) or (C,3) added where alpha < 1; radius_clip: cull Gaussians whose pixel
    radius is <= this. Returns rgb (...,H,W,3), alpha (...,H,W) accumulated opacity, depth
    (...,H,W) expected depth (sum of w_i z_i / alpha; 0 where alpha is 0), meta.
    """
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
    deg = check_gaussians(means, quats, log_scales, opacity_logits, colors, sh_degree)
    check_image(width, height, near, far)
    cams = prepare_cameras(world_T_cam, K)
    background_rows(background, len(cams), means.dtype, means.device)      # shape and finiteness, up front
    if backend == "gsplat-reference":
        from nuav2.splat.gsplat_reference import rasterize_gsplat_reference

        return rasterize_gsplat_reference(means, quats, log_scales, opacity_logits, colors, cams, int(width),
                                          int(height), near, far, background, deg, radius_clip)
    if backend in ("auto", "gsplat"):
        from nuav2.splat import gsplat_backend

        ok, why = gsplat_backend.gsplat_available()
        if backend == "gsplat" and not ok:
            raise RuntimeError(f"backend='gsplat' unavailable: {why}")
        if ok and means.is_cuda:
            return gsplat_backend.rasterize_gsplat(means, quats, log_scales, opacity_logits, colors, cams,
                                                   int(width), int(height), near, far, background, deg,
                                                   radius_clip)
        if backend == "gsplat":
            raise RuntimeError("backend='gsplat' needs the Gaussian tensors on a CUDA device")
    device = means.device
    if device.type != "cpu":
        means, quats, log_scales, opacity_logits, colors = (
            t.cpu() for t in (means, quats, log_scales, opacity_logits, colors))
        if isinstance(background, torch.Tensor):
            background = background.cpu()
    out = _rasterize_cpu(means, quats, log_scales, opacity_logits, colors, cams, int(width), int(height),
                         near, far, background, deg, radius_clip)
    if device.type == "cpu":
        return out
    # images go back to the caller's device; meta stays on the CPU so that meta["means2d"]
    # remains the graph node that receives gradients (and .absgrad)
    return RasterOutput(out.rgb.to(device), out.alpha.to(device), out.depth.to(device), out.meta)


def _rasterize_cpu(means, quats, log_scales, opacity_logits, colors, cams, width, height, near, far,
                   background, sh_degree, radius_clip) -> RasterOutput:
    n_cams = len(cams)
    dtype = means.dtype
    opacities = torch.sigmoid(opacity_logits)
    means2d, conics, depths, radii = ProjectFn.apply(
        means, quats, log_scales, opacities.detach(), cams.cam_T_world, cams.K, width, height, near, far,
        radius_clip)
    absgrad = torch.zeros(n_cams, len(means), 2, dtype=dtype)
    means2d.absgrad = absgrad
    radii_np = radii.numpy()
    colors, bad_colors = finite_colors(colors)
    bg = None if background is None else background_rows(background, n_cams, dtype, means.device)
    rgbs, alphas, exp_depths = [], [], []
    for c in range(n_cams):
        col, bad = camera_colors(colors, bad_colors, sh_degree, means, cams.centres_world[c])
        if bad is not None:
            radii_np[c][bad.numpy()] = 0          # culled: also skipped by the projection backward
        color_sum, depth_sum, alpha = CompositeFn.apply(
            means2d[c], conics[c], opacities, col, depths[c], radii_np[c], width, height, absgrad[c])
        rgbs.append(color_sum if bg is None else color_sum + (1.0 - alpha)[..., None] * bg[c])
        alphas.append(alpha)
        exp_depths.append(depth_sum / alpha.clamp_min(ALPHA_FLOOR_DEPTH))
    return _finish(rgbs, alphas, exp_depths, cams.batched, dict(
        means2d=means2d, radii=radii, visible=(radii > 0).any(-1), depths=depths,
        conics=conics, backend="cpu"))


def radii_to_int(radii: torch.Tensor) -> torch.Tensor:
    """Float pixel radii -> int32 (clamped; only huge off-screen splats ever reach the clamp)."""
    return radii.clamp(0, _INT32_MAX).to(torch.int32)


def _finish(rgbs, alphas, depths, batched: bool, meta: dict) -> RasterOutput:
    if batched:
        return RasterOutput(torch.stack(rgbs), torch.stack(alphas), torch.stack(depths), meta)
    return RasterOutput(rgbs[0], alphas[0], depths[0], meta)
