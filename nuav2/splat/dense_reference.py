"""Dense plain-torch reference rasterizer: every visible Gaussian against every pixel, autograd only.

Same inputs, outputs and rules as :func:`nuav2.splat.rasterize` (gsplat v1.5.3 constants:
EWA projection with the 1.3x FoV Jacobian clamp and the 0.3 px low-pass, opacity-aware
radius culling, alpha clamp 0.999, alpha < 1/255 skipped, stop once T*(1-alpha) <= 1e-4),
written as the textbook formulas with T from ``cumprod``. Memory is O(N*H*W): for tests and
benchmarks only.
"""

from __future__ import annotations

import torch

from nuav2.splat._inputs import (
    background_rows,
    camera_colors,
    check_gaussians,
    check_image,
    finite_colors,
    prepare_cameras,
)
from nuav2.splat._project import MEAN2D_LIMIT
from nuav2.splat.constants import (
    ALPHA_FLOOR_DEPTH,
    ALPHA_MAX,
    ALPHA_MIN,
    EPS2D,
    EXTEND_MAX,
    FOV_CLAMP,
    LOG_SCALE_MAX,
    LOG_SCALE_MIN,
    QUAT_EPS,
    T_STOP,
)
from nuav2.splat.rasterize import RasterOutput, _finish, radii_to_int

DEFAULT_MAX_ELEMENTS = 40_000_000  # visible Gaussians x pixels per camera


def quat_to_rotmat(quats: torch.Tensor) -> torch.Tensor:
    """(N,4) wxyz -> (N,3,3), dividing by max(|q|, eps) first."""
    q = quats / quats.norm(dim=-1, keepdim=True).clamp_min(QUAT_EPS)
    w, x, y, z = q.unbind(-1)
    return torch.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], -1).reshape(-1, 3, 3)


def project_dense(means, quats, log_scales, opacities, cam_T_world, K, width, height, near, far,
                  radius_clip):
    """float64 EWA projection of all Gaussians; returns means2d, conics, depths, radii, visible."""
    m = means.to(torch.float64)
    V = torch.as_tensor(cam_T_world, dtype=torch.float64)
    Kt = torch.as_tensor(K, dtype=torch.float64)
    p = m @ V[:3, :3].T + V[:3, 3]
    x, y, z = p.unbind(-1)
    R = quat_to_rotmat(quats.to(torch.float64))
    s = torch.exp(log_scales.to(torch.float64).clamp(LOG_SCALE_MIN, LOG_SCALE_MAX))
    M = R * s[:, None, :]                              # covariance M M^T
    fx, fy, cx, cy = Kt[0, 0], Kt[1, 1], Kt[0, 2], Kt[1, 2]
    zs = torch.where(z > 0, z, torch.ones_like(z))     # culled anyway; keeps the graph finite
    lim_x = (cx / fx + FOV_CLAMP * 0.5 * width / fx, (width - cx) / fx + FOV_CLAMP * 0.5 * width / fx)
    lim_y = (cy / fy + FOV_CLAMP * 0.5 * height / fy, (height - cy) / fy + FOV_CLAMP * 0.5 * height / fy)
    tx = zs * torch.clamp(x / zs, -float(lim_x[0]), float(lim_x[1]))
    ty = zs * torch.clamp(y / zs, -float(lim_y[0]), float(lim_y[1]))
    zero = torch.zeros_like(zs)
    J = torch.stack([fx / zs, zero, -fx * tx / zs**2, zero, fy / zs, -fy * ty / zs**2], -1).reshape(-1, 2, 3)
    A = J @ V[:3, :3] @ M                              # cov2d = A A^T + 0.3 I
    cov2d = A @ A.transpose(1, 2) + EPS2D * torch.eye(2, dtype=torch.float64)
    a, b, c = cov2d[:, 0, 0], cov2d[:, 0, 1], cov2d[:, 1, 1]
    # det(A A^T + e I) = sum of squared 2x2 minors (Cauchy-Binet) + e tr(A A^T) + e^2: no cancellation
    minors = torch.stack([A[:, 0, i] * A[:, 1, j] - A[:, 0, j] * A[:, 1, i]
                          for i, j in ((0, 1), (0, 2), (1, 2))])
    det = (minors**2).sum(0) + EPS2D * (a + c - 2 * EPS2D) + EPS2D**2
    det_safe = torch.where(det > 0, det, torch.ones_like(det))
    conics = torch.stack([c / det_safe, -b / det_safe, a / det_safe], -1)
    means2d = torch.stack([fx * x / zs + cx, fy * y / zs + cy], -1)
    with torch.no_grad():
        o = opacities.detach().to(torch.float64)
        extend = torch.sqrt(2.0 * torch.log(o.clamp_min(ALPHA_MIN) / ALPHA_MIN)).clamp_max(EXTEND_MAX)
        radii = torch.ceil(extend[:, None] * torch.sqrt(torch.stack([a, c], -1).clamp_min(0)))
        u, v = means2d.unbind(-1)
        rx, ry = radii.unbind(-1)
        visible = ((z >= near) & (z <= far) & (o >= ALPHA_MIN) & (det > 0)
                   & ~((rx <= radius_clip) & (ry <= radius_clip))
                   & ~((u + rx <= 0) | (u - rx >= width) | (v + ry <= 0) | (v - ry >= height))
                   & (u.abs() <= MEAN2D_LIMIT) & (v.abs() <= MEAN2D_LIMIT)
                   & torch.isfinite(conics).all(-1) & torch.isfinite(radii).all(-1))
        radii = torch.where(visible[:, None], radii, torch.zeros_like(radii))
    return means2d, conics, z, radii, visible


def composite_dense(means2d, conics, opacities, colors, depths, width, height):
    """Per-pixel front-to-back compositing of depth-sorted Gaussians -> colour sum, depth sum, alpha."""
    dtype = means2d.dtype
    px = torch.arange(width, dtype=torch.float64).add(0.5).to(dtype)
    py = torch.arange(height, dtype=torch.float64).add(0.5).to(dtype)
    gy, gx = torch.meshgrid(py, px, indexing="ij")
    dx = means2d[:, 0, None] - gx.reshape(1, -1)
    dy = means2d[:, 1, None] - gy.reshape(1, -1)
    a, b, c = conics[:, 0, None], conics[:, 1, None], conics[:, 2, None]
    sigma = 0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy
    alpha = torch.clamp(opacities[:, None] * torch.exp(-sigma), max=ALPHA_MAX)
    with torch.no_grad():
        used = (sigma >= 0) & (alpha >= ALPHA_MIN)
    alpha = torch.where(used, alpha, torch.zeros_like(alpha))
    with torch.no_grad():
        keep = torch.cumprod(1 - alpha, dim=0) > T_STOP
    alpha = alpha * keep
    T_incl = torch.cumprod(1 - alpha, dim=0)
    T_excl = torch.cat([torch.ones_like(T_incl[:1]), T_incl[:-1]], 0)
    w = alpha * T_excl
    color = (w.T @ colors).reshape(height, width, 3)
    depth = (w.T @ depths).reshape(height, width)
    final_T = T_incl[-1] if len(T_incl) else torch.ones(height * width, dtype=dtype)
    return color, depth, (1 - final_T).reshape(height, width)


def rasterize_dense(means, quats, log_scales, opacity_logits, colors, world_T_cam, K, width: int,
                    height: int, *, near: float = 0.01, far: float = 1e10, background=None,
                    sh_degree: int | None = None, radius_clip: float = 0.0,
                    max_elements: int = DEFAULT_MAX_ELEMENTS) -> RasterOutput:
    """Same contract as :func:`nuav2.splat.rasterize`; raises MemoryError past max_elements."""
    deg = check_gaussians(means, quats, log_scales, opacity_logits, colors, sh_degree)
    check_image(width, height, near, far)
    cams = prepare_cameras(world_T_cam, K)
    dtype = means.dtype
    opacities = torch.sigmoid(opacity_logits)
    bg = background_rows(background, len(cams), dtype, means.device)
    colors, bad_colors = finite_colors(colors)
    rgbs, alphas, exp_depths, metas = [], [], [], []
    for ci in range(len(cams)):
        means2d, conics, z, radii, visible = project_dense(
            means, quats, log_scales, opacities, cams.cam_T_world[ci], cams.K[ci], width, height, near, far,
            radius_clip)
        col, bad = camera_colors(colors, bad_colors, deg, means, cams.centres_world[ci])
        if bad is not None:
            visible = visible & ~bad
            radii = torch.where(visible[:, None], radii, torch.zeros_like(radii))
        idx = torch.nonzero(visible).flatten()
        if len(idx) * width * height > max_elements:
            raise MemoryError(f"dense reference: {len(idx)} Gaussians x {width}x{height} px exceeds "
                              f"max_elements={max_elements}")
        zd = z.to(dtype)
        idx = idx[torch.argsort(zd[idx], stable=True)]
        color_sum, depth_sum, alpha = composite_dense(
            means2d[idx].to(dtype), conics[idx].to(dtype), opacities[idx], col[idx], zd[idx], width, height)
        rgbs.append(color_sum + (1.0 - alpha)[..., None] * bg[ci])
        alphas.append(alpha)
        exp_depths.append(depth_sum / alpha.clamp_min(ALPHA_FLOOR_DEPTH))
        metas.append((means2d.to(dtype), radii, visible, zd, conics.to(dtype)))
    m2, radii, vis, dep, con = (torch.stack(t) for t in zip(*metas))
    return _finish(rgbs, alphas, exp_depths, cams.batched, dict(
        means2d=m2, radii=radii_to_int(radii), visible=vis, depths=dep, conics=con, backend="dense"))
