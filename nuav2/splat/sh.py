"""Real spherical harmonics (degree 0-3) to RGB in plain torch, as in 3DGS/gsplat.

Colour = clamp_min(sum_k c_k Y_k(dir) + 0.5, 0) with dir the unit vector from the camera centre
to the Gaussian; autograd gives the gradients to the coefficients and to the means.
"""

from __future__ import annotations

import math

import torch

_C0 = 0.28209479177387814
_C1 = 0.4886025119029199
_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792,
       0.5462742152960396)
_C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
       -0.4570457994644658, 1.445305721320277, -0.5900435899266435)
MAX_SH_DEGREE = 3


def sh_degree_of(n_coeffs: int) -> int:
    """Degree d with (d+1)^2 == n_coeffs, or ValueError."""
    d = math.isqrt(n_coeffs) - 1
    if (d + 1) ** 2 != n_coeffs or d > MAX_SH_DEGREE:
        raise ValueError(f"colors must have (d+1)^2 SH coefficients with d <= {MAX_SH_DEGREE}, "
                         f"got {n_coeffs}")
    return d


def eval_sh(coeffs: torch.Tensor, dirs: torch.Tensor, degree: int) -> torch.Tensor:
    """sum_k coeffs[:, k] * Y_k(dirs) for the first (degree+1)^2 basis functions; dirs unit (N,3)."""
    out = _C0 * coeffs[:, 0]
    if degree < 1:
        return out
    x, y, z = (dirs[:, i : i + 1] for i in range(3))
    out = out - _C1 * y * coeffs[:, 1] + _C1 * z * coeffs[:, 2] - _C1 * x * coeffs[:, 3]
    if degree < 2:
        return out
    xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
    out = (out + _C2[0] * xy * coeffs[:, 4] + _C2[1] * yz * coeffs[:, 5]
           + _C2[2] * (2.0 * zz - xx - yy) * coeffs[:, 6] + _C2[3] * xz * coeffs[:, 7]
           + _C2[4] * (xx - yy) * coeffs[:, 8])
    if degree < 3:
        return out
    return (out + _C3[0] * y * (3.0 * xx - yy) * coeffs[:, 9] + _C3[1] * xy * z * coeffs[:, 10]
            + _C3[2] * y * (4.0 * zz - xx - yy) * coeffs[:, 11]
            + _C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy) * coeffs[:, 12]
            + _C3[4] * x * (4.0 * zz - xx - yy) * coeffs[:, 13] + _C3[5] * z * (xx - yy) * coeffs[:, 14]
            + _C3[6] * x * (xx - 3.0 * yy) * coeffs[:, 15])


def sh_to_rgb(coeffs: torch.Tensor, means: torch.Tensor, cam_centre_world, degree: int) -> torch.Tensor:
    """View-dependent RGB (N,3) seen from cam_centre_world (3,), float64 direction math."""
    centre = torch.as_tensor(cam_centre_world, dtype=torch.float64, device=means.device)
    d = means.to(torch.float64) - centre
    dirs = d / d.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    return torch.clamp_min(eval_sh(coeffs, dirs.to(coeffs.dtype), degree) + 0.5, 0.0)
