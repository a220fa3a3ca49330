"""Small random Gaussian scenes and cameras shared by the rasterizer tests."""

from __future__ import annotations

import numpy as np
import torch

from nuav2.geometry import T_from_quat_trans, quat_normalize

PARAMS = ("means", "quats", "log_scales", "opacity_logits", "colors")


def pinhole(width: int, height: int, f: float | None = None) -> np.ndarray:
    f = f if f is not None else 0.8 * width
    return np.array([[f, 0.0, width / 2.0], [0.0, f, height / 2.0], [0.0, 0.0, 1.0]])


def random_pose(seed: int) -> np.ndarray:
    """A random rigid world_T_cam (OpenCV camera)."""
    rng = np.random.default_rng(seed)
    return T_from_quat_trans(quat_normalize(rng.normal(size=4)), rng.normal(0.0, 3.0, 3))


def random_gaussians(n: int, seed: int, world_T_cam: np.ndarray | None = None, dtype=torch.float32,
                     depth=(2.0, 9.0), half_fov=0.7, log_scale=(-2.5, -0.7), sh_degree: int | None = None,
                     ) -> dict[str, torch.Tensor]:
    """n Gaussians spread over the view frustum of world_T_cam (identity when None)."""
    rng = np.random.default_rng(seed)
    z = rng.uniform(*depth, n)
    xy = rng.uniform(-half_fov, half_fov, (n, 2)) * z[:, None]
    pts_cam = np.column_stack([xy, z])
    pose = np.eye(4) if world_T_cam is None else world_T_cam
    means = pts_cam @ pose[:3, :3].T + pose[:3, 3]
    if sh_degree is None:
        colors = rng.uniform(0.0, 1.0, (n, 3))
    else:
        colors = rng.normal(0.0, 0.4, (n, (sh_degree + 1) ** 2, 3))
    out = {"means": means, "quats": rng.normal(size=(n, 4)),
           "log_scales": rng.uniform(*log_scale, (n, 3)),
           "opacity_logits": rng.normal(0.5, 2.0, n), "colors": colors}
    return {k: torch.tensor(v, dtype=dtype) for k, v in out.items()}


def leaves(params: dict[str, torch.Tensor], requires_grad: bool = True) -> list[torch.Tensor]:
    """Fresh leaf tensors in PARAMS order."""
    return [params[k].detach().clone().requires_grad_(requires_grad) for k in PARAMS]


def weighted_loss(out, seed: int = 0) -> torch.Tensor:
    """A scalar touching rgb, alpha and depth with random per-pixel weights."""
    g = torch.Generator().manual_seed(seed)
    wr = torch.rand(out.rgb.shape, generator=g, dtype=torch.float64).to(out.rgb)
    wa = torch.rand(out.alpha.shape, generator=g, dtype=torch.float64).to(out.rgb)
    wd = torch.rand(out.depth.shape, generator=g, dtype=torch.float64).to(out.rgb)
    return (out.rgb * wr).sum() + (out.alpha * wa).sum() + 0.05 * (out.depth * wd).sum()


def grads_of(fn, params: dict[str, torch.Tensor], *args, seed: int = 0, **kwargs):
    """(output, [grad per parameter]) of weighted_loss(fn(params, *args))."""
    ts = leaves(params)
    out = fn(*ts, *args, **kwargs)
    weighted_loss(out, seed).backward()
    return out, [t.grad for t in ts]


def max_rel(a: torch.Tensor, b: torch.Tensor) -> float:
    """max |a - b| / max |b| (0 when both vanish)."""
    scale = float(b.abs().max()) if b.numel() else 0.0
    err = float((a - b).abs().max()) if b.numel() else 0.0
    return 0.0 if scale == 0.0 and err == 0.0 else err / max(scale, 1e-30)
