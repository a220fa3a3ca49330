"""gsplat (CUDA) backend with the same inputs and outputs as the CPU rasterizer.

gsplat is imported lazily: it is optional, and ``import gsplat`` alone JIT-compiles nothing.
Zero quaternions become the identity (gsplat's own normalisation would give NaN), log-scales
are clamped like the CPU path, and the background is composited here so both backends agree.

What densification reads is already in nuav2's convention in gsplat 1.5.3 (checked against its
source, ``cuda/csrc/RasterizeToPixels3DGSBwd.cu`` and ``ProjectionEWA3DGSFused.cu``):
``means2d`` are pixel positions with pixel j's centre at j + 0.5, its ``.grad`` is the sum over
pixels of dL/dmeans2d in pixel units (the trainer turns it into NDC units by x W/2, H/2, as
gsplat's own strategy does), ``.absgrad`` the sum of the per-pixel absolute values, and
``radii`` (C,N,2) int32 per-axis pixel radii from the same opacity-aware bound, 0 on both
axes for a culled Gaussian. Two things differ and are converted in :func:`from_gsplat`: gsplat
leaves ``depths`` and ``conics`` of culled Gaussians unwritten (``at::empty``), here they are 0
as on the CPU; gsplat < 1.5 gives one radius per Gaussian, here it is repeated per axis.
"""

from __future__ import annotations

import functools
import importlib.util
import os
from pathlib import Path

import torch

from nuav2.machine_lock import machine_lock
from nuav2.splat._inputs import Cameras, background_rows, finite_colors
from nuav2.splat.constants import (
    EPS2D,
    LOG_SCALE_MAX,
    LOG_SCALE_MIN,
    QUAT_EPS,
)


def gsplat_build_lock_path() -> Path:
    """Where processes on one machine queue for gsplat's CUDA build (beside torch's extension cache)."""
    root = os.environ.get("TORCH_EXTENSIONS_DIR") or Path.home() / ".cache" / "torch_extensions"
    return Path(root) / "nuav2-gsplat-build.lock"


@functools.lru_cache(maxsize=1)
def load_gsplat_cuda() -> bool:
    """Load gsplat's CUDA extension in this process, one process per machine at a time. gsplat
    compiles it on first use, and an importing process starts by deleting the build folder's lock
    and, while no library is built there yet, the folder (gsplat 1.5.3, ``cuda/_backend.py``): render
    tasks starting together on a fresh node broke each other's builds. Queued here, the first one
    compiles and the others load its library. True when the extension loaded."""
    with machine_lock(gsplat_build_lock_path()):
        from gsplat.cuda._backend import _C
    return _C is not None


@functools.lru_cache(maxsize=1)
def gsplat_available() -> tuple[bool, str]:
    """(True, "") when CUDA and the gsplat package are usable, else (False, why)."""
    if not torch.cuda.is_available():
        return False, "no CUDA device (torch.cuda.is_available() is False)"
    if importlib.util.find_spec("gsplat") is None:
        return False, "the gsplat package is not installed"
    return True, ""


def gsplat_inputs(means, quats, log_scales, opacity_logits, colors, cams: Cameras) -> dict:
    """nuav2's raw parameters and cameras as ``gsplat.rasterization``'s first seven arguments."""
    device, dtype = means.device, means.dtype
    norm = quats.norm(dim=-1, keepdim=True)
    identity = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=dtype, device=device)
    unit_quats = torch.where(norm >= QUAT_EPS, quats / norm.clamp_min(QUAT_EPS), identity)
    colors, bad_colors = finite_colors(colors)          # culled as on the CPU: opacity 0 < 1/255
    opacities = torch.sigmoid(opacity_logits)
    if bad_colors is not None:
        opacities = torch.where(bad_colors, torch.zeros_like(opacities), opacities)
    return {"means": means, "quats": unit_quats,
            "scales": torch.exp(log_scales.clamp(LOG_SCALE_MIN, LOG_SCALE_MAX)), "opacities": opacities,
            "colors": colors, "viewmats": torch.as_tensor(cams.cam_T_world, dtype=dtype, device=device),
            "Ks": torch.as_tensor(cams.K, dtype=dtype, device=device)}


def from_gsplat(renders: torch.Tensor, alphas: torch.Tensor, meta: dict, background, cams: Cameras,
                backend: str):
    """gsplat's RGB+ED ``renders`` (C,H,W,4), ``alphas`` (C,H,W,1) and ``meta`` as a nuav2
    ``RasterOutput`` (background composited here; see the module docstring for the meta)."""
    from nuav2.splat.rasterize import RasterOutput, radii_to_int

    alpha = alphas[..., 0]
    bg = background_rows(background, len(cams), renders.dtype, renders.device)
    rgb = renders[..., :3] + (1.0 - alpha)[..., None] * bg[:, None, None, :]
    depth = renders[..., 3]
    radii = meta["radii"]
    if radii.ndim == 2:                       # gsplat < 1.5 gives one radius per Gaussian
        radii = radii[..., None].expand(*radii.shape, 2)
    radii = radii_to_int(radii.float())
    visible = (radii > 0).any(-1)
    depths = torch.where(visible, meta["depths"], torch.zeros_like(meta["depths"]))
    conics = torch.where(visible[..., None], meta["conics"], torch.zeros_like(meta["conics"]))
    out_meta = dict(means2d=meta["means2d"], radii=radii, visible=visible, depths=depths, conics=conics,
                    backend=backend)
    if not cams.batched:
        return RasterOutput(rgb[0], alpha[0], depth[0], out_meta)
    return RasterOutput(rgb, alpha, depth, out_meta)


def rasterize_gsplat(means, quats, log_scales, opacity_logits, colors, cams: Cameras, width: int,
                     height: int, near: float, far: float, background, sh_degree: int | None,
                     radius_clip: float):
    """Render through ``gsplat.rasterization`` (classic mode, RGB+ED) and repackage the outputs."""
    import gsplat

    if not load_gsplat_cuda():
        raise RuntimeError("gsplat's CUDA extension did not build or load (gsplat printed why); "
                           "use --device cpu to train on the CPU")
    renders, alphas, meta = gsplat.rasterization(
        **gsplat_inputs(means, quats, log_scales, opacity_logits, colors, cams), width=width, height=height,
        near_plane=near, far_plane=far, radius_clip=radius_clip, eps2d=EPS2D, sh_degree=sh_degree,
        packed=False, render_mode="RGB+ED", absgrad=True, rasterize_mode="classic")
    return from_gsplat(renders, alphas, meta, background, cams, "gsplat")
