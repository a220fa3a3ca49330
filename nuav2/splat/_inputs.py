"""Input checks and camera preparation shared by every rasterizer backend and the dense reference."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from nuav2.splat.sh import sh_degree_of, sh_to_rgb

_RIGID_TOL = 1e-4


@dataclass(frozen=True)
class Cameras:
    """Cameras in float64: cam_T_world (C,4,4) for projection, K (C,3,3), centres (C,3)."""

    cam_T_world: np.ndarray
    K: np.ndarray
    centres_world: np.ndarray
    batched: bool

    def __len__(self) -> int:
        return len(self.cam_T_world)


def _as_f64(x, name: str) -> np.ndarray:
    if isinstance(x, torch.Tensor):
        x = x.detach().cpu().to(torch.float64).numpy()
    arr = np.asarray(x, dtype=np.float64)
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite")
    return arr


def prepare_cameras(world_T_cam, K) -> Cameras:
    """Invert rigid OpenCV world_T_cam poses (x right, y down, z forward) in float64."""
    world_T_cam = _as_f64(world_T_cam, "world_T_cam")
    K = _as_f64(K, "K")
    batched = world_T_cam.ndim == 3
    if world_T_cam.shape[-2:] != (4, 4) or world_T_cam.ndim not in (2, 3):
        raise ValueError(f"world_T_cam must be (4,4) or (C,4,4), got {world_T_cam.shape}")
    world_T_cam = world_T_cam.reshape(-1, 4, 4)
    n_cams = len(world_T_cam)
    if K.shape == (3, 3):
        K = np.broadcast_to(K, (n_cams, 3, 3))
    if K.shape != (n_cams, 3, 3):
        raise ValueError(f"K must be (3,3) or ({n_cams},3,3) to match world_T_cam, got {K.shape}")
    if np.any(K[:, 0, 0] <= 0) or np.any(K[:, 1, 1] <= 0):
        raise ValueError("K must have positive focal lengths fx, fy")
    R = world_T_cam[:, :3, :3]
    ortho_err = np.abs(R @ np.swapaxes(R, 1, 2) - np.eye(3)).max(initial=0.0)
    if ortho_err > _RIGID_TOL or np.abs(world_T_cam[:, 3] - [0, 0, 0, 1]).max(initial=0.0) > _RIGID_TOL:
        raise ValueError(f"world_T_cam must be rigid 4x4 poses (rotation error {ortho_err:.2e})")
    cam_T_world = np.zeros_like(world_T_cam)
    cam_T_world[:, :3, :3] = np.swapaxes(R, 1, 2)
    cam_T_world[:, :3, 3] = -np.einsum("cji,cj->ci", R, world_T_cam[:, :3, 3])
    cam_T_world[:, 3, 3] = 1.0
    K = np.array(K, dtype=np.float64, order="C")          # a writable copy (K may be a broadcast view)
    return Cameras(cam_T_world, K, world_T_cam[:, :3, 3].copy(), batched)


def check_gaussians(means: torch.Tensor, quats: torch.Tensor, log_scales: torch.Tensor,
                    opacity_logits: torch.Tensor, colors: torch.Tensor, sh_degree: int | None) -> int | None:
    """Validate shapes/dtypes; returns the SH degree to use, or None for plain RGB colours."""
    if not isinstance(means, torch.Tensor) or means.ndim != 2 or means.shape[1] != 3:
        raise ValueError(f"means must be a (N,3) tensor, got {getattr(means, 'shape', type(means))}")
    n = means.shape[0]
    if means.dtype not in (torch.float32, torch.float64):
        raise ValueError(f"means must be float32 or float64, got {means.dtype}")
    for name, t, shape in (("quats", quats, (n, 4)), ("log_scales", log_scales, (n, 3)),
                           ("opacity_logits", opacity_logits, (n,))):
        if not isinstance(t, torch.Tensor) or tuple(t.shape) != shape:
            raise ValueError(f"{name} must be a tensor of shape {shape}, got {getattr(t, 'shape', type(t))}")
        if t.dtype != means.dtype:
            raise ValueError(f"{name} dtype {t.dtype} differs from means dtype {means.dtype}")
    if not isinstance(colors, torch.Tensor) or colors.dtype != means.dtype:
        raise ValueError(f"colors must be a tensor with the dtype of means ({means.dtype})")
    if colors.shape == (n, 3):
        if sh_degree is not None:
            raise ValueError("sh_degree given but colors are plain RGB (N,3); pass SH as (N,K,3)")
        return None
    if colors.ndim == 3 and colors.shape[0] == n and colors.shape[2] == 3:
        full = sh_degree_of(colors.shape[1])
        if sh_degree is None:
            return full
        if not 0 <= sh_degree <= full:
            raise ValueError(f"sh_degree {sh_degree} outside 0..{full} for {colors.shape[1]} coefficients")
        return sh_degree
    raise ValueError(f"colors must be (N,3) RGB or (N,K,3) SH with N={n}, got {tuple(colors.shape)}")


def check_image(width: int, height: int, near: float, far: float) -> None:
    if int(width) != width or int(height) != height or width <= 0 or height <= 0:
        raise ValueError(f"width/height must be positive integers, got {width}x{height}")
    if not (0.0 < near < far):
        raise ValueError(f"need 0 < near < far, got near={near}, far={far}")


def background_rows(background, n_cams: int, dtype: torch.dtype, device) -> torch.Tensor:
    """Background as (C,3) in the image dtype (zeros when None); a non-finite one is an error
    (it would reach every pixel that is not fully opaque)."""
    if background is None:
        return torch.zeros(n_cams, 3, dtype=dtype, device=device)
    bg = torch.as_tensor(background, dtype=dtype, device=device)
    if not torch.isfinite(bg.detach()).all():
        raise ValueError(f"background must be finite, got {bg.detach().cpu().tolist()}")
    if bg.shape == (3,):
        return bg.expand(n_cams, 3)
    if bg.shape == (n_cams, 3):
        return bg
    raise ValueError(f"background must be (3,) or ({n_cams},3), got {tuple(bg.shape)}")


def finite_colors(colors: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
    """(colours with the rows of non-finite Gaussians zeroed, (N,) bool mask of those Gaussians,
    None when there is none: a finite sum proves it with one pass).

    A Gaussian whose colour (or any SH coefficient) is NaN or inf is culled by every backend,
    like one with a non-finite mean, scale, rotation or opacity: it would otherwise turn every
    pixel behind it, and the gradients of its neighbours, into NaN. Zeroing the rows (with
    ``torch.where``) keeps NaN out of the backward graph, so the culled Gaussian's colour
    gradient is exactly zero.
    """
    if bool(torch.isfinite(colors.detach().sum())):
        return colors, None
    bad = ~torch.isfinite(colors.detach()).flatten(1).all(-1)
    if not bad.any():
        return colors, None
    mask = bad.reshape((-1,) + (1,) * (colors.ndim - 1))
    return torch.where(mask, torch.zeros_like(colors), colors), bad


def camera_colors(colors: torch.Tensor, bad: torch.Tensor | None, sh_degree: int | None, means: torch.Tensor,
                  centre_world: np.ndarray) -> tuple[torch.Tensor, torch.Tensor | None]:
    """RGB per Gaussian for one camera (SH evaluated towards it) and the Gaussians to cull there
    (None for none): ``bad`` plus any whose SH colour overflowed (zeroed too)."""
    if sh_degree is None:
        return colors, bad
    rgb = sh_to_rgb(colors, means, centre_world, sh_degree)
    rgb, overflow = finite_colors(rgb)
    if overflow is None:
        return rgb, bad
    return rgb, overflow if bad is None else bad | overflow
