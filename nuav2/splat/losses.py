"""Training losses: photometric (L1 + SSIM), LiDAR depth, sky/opacity, flatness, plus PSNR for progress.

Images are (H, W, 3) float tensors in [0, 1]. ``valid`` masks (H, W) bool mark pixels that
carry scene content (False under the ego-vehicle body): there the target is replaced by the
detached prediction, so those pixels give no error and SSIM windows straddling the mask edge
compare like with like.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from nuav2.splat.constants import LOG_SCALE_MAX, LOG_SCALE_MIN

SSIM_C1 = 0.01**2
SSIM_C2 = 0.03**2


def _gauss_1d(size: int, sigma: float, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """The normalised window, computed in float64 on the CPU (the same on every device)."""
    x = torch.arange(size, dtype=torch.float64) - (size - 1) / 2
    g = torch.exp(-(x**2) / (2 * sigma**2))
    return (g / g.sum()).to(dtype).to(device)


def ssim_map(x: torch.Tensor, y: torch.Tensor, window: int = 11, sigma: float = 1.5) -> torch.Tensor:
    """Per-pixel SSIM (H, W) of two (H, W, 3) images, Gaussian window, zero padding (as 3DGS).

    The Gaussian window is separable: a row then a column pass equal the 2D filter exactly
    (zero padding included) at a fraction of the cost."""
    g = _gauss_1d(window, sigma, x.dtype, x.device)
    w_row = g.reshape(1, 1, 1, -1).expand(5 * 3, 1, 1, window).contiguous()
    w_col = g.reshape(1, 1, -1, 1).expand(5 * 3, 1, window, 1).contiguous()
    a = x.permute(2, 0, 1)
    b = y.permute(2, 0, 1)
    pad = window // 2
    stack = torch.cat([a, b, a * a, b * b, a * b])[None]  # all five moments in one grouped conv
    f = F.conv2d(F.conv2d(stack, w_row, padding=(0, pad), groups=15), w_col, padding=(pad, 0), groups=15)[0]
    mu_a, mu_b, e_aa, e_bb, e_ab = f.split(3)
    var_a = e_aa - mu_a**2
    var_b = e_bb - mu_b**2
    cov = e_ab - mu_a * mu_b
    num = (2 * mu_a * mu_b + SSIM_C1) * (2 * cov + SSIM_C2)
    den = (mu_a**2 + mu_b**2 + SSIM_C1) * (var_a + var_b + SSIM_C2)
    return (num / den).mean(0)


def masked_target(pred: torch.Tensor, target: torch.Tensor, valid: torch.Tensor | None) -> torch.Tensor:
    if valid is None:
        return target
    return torch.where(valid[..., None], target, pred.detach())


def photo_behind_mask(pred: torch.Tensor, target: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """The render where ``valid``, the photo elsewhere (the ego's body): no gradient reaches what the render
    puts behind the mask. Masking the loss alone is not enough: SSIM windows that straddle the mask edge
    still pull on the masked pixels, and so on the road under and behind the ego, which no image sees;
    it turned see-through and a target camera looking back showed the sky's colour on the road."""
    return torch.where(valid[..., None], pred, target)


def photometric_loss(pred: torch.Tensor, target: torch.Tensor, valid: torch.Tensor | None = None,
                     lambda_ssim: float = 0.2) -> tuple[torch.Tensor, float, float]:
    """(1 - lambda) L1 + lambda (1 - SSIM) over valid pixels; returns (loss, l1, ssim)."""
    tgt = masked_target(pred, target, valid)
    l1_map = (pred - tgt).abs().mean(-1)
    s_map = ssim_map(pred, tgt)
    if valid is None:
        l1, s = l1_map.mean(), s_map.mean()
    else:
        n = valid.sum().clamp_min(1)
        l1, s = (l1_map * valid).sum() / n, (s_map * valid).sum() / n
    loss = (1 - lambda_ssim) * l1 + lambda_ssim * (1 - s)
    return loss, float(l1.detach()), float(s.detach())


def depth_loss(depth: torch.Tensor, alpha: torch.Tensor, samples_uvz: torch.Tensor, trim: float = 0.95,
               min_alpha: float = 0.5) -> torch.Tensor:
    """Relative L1 between rendered expected depth and LiDAR depth at the samples' pixels.

    ``samples_uvz`` (M, 3): pixel column, row (rig convention, rounded to the nearest pixel) and
    LiDAR z-depth. Only pixels the Gaussians cover (alpha > min_alpha) count, and only the
    smallest ``trim`` fraction of errors (LiDAR-camera parallax and mixed edge pixels are the
    rest), as in Street Gaussians.
    """
    if samples_uvz.numel() == 0:
        return depth.sum() * 0.0
    h, w = depth.shape
    u = samples_uvz[:, 0].round().long().clamp(0, w - 1)
    v = samples_uvz[:, 1].round().long().clamp(0, h - 1)
    z = samples_uvz[:, 2]
    a = alpha[v, u]
    keep = a.detach() > min_alpha
    if not bool(keep.any()):
        return depth.sum() * 0.0
    err = (depth[v, u][keep] - z[keep]).abs() / z[keep].clamp_min(1e-3)
    k = max(1, int(math.floor(trim * len(err))))
    return torch.topk(err, k, largest=False).values.mean()


def sky_loss(alpha: torch.Tensor, sky_mask: torch.Tensor | None, eps: float = 1e-4) -> torch.Tensor:
    """Binary cross-entropy pushing the Gaussians' accumulated opacity to 0 on sky pixels."""
    if sky_mask is None or not bool(sky_mask.any()):
        return alpha.sum() * 0.0
    return -torch.log((1 - alpha[sky_mask]).clamp_min(eps)).mean()


def flatness_loss(log_scales: torch.Tensor) -> torch.Tensor:
    """Mean of each Gaussian's smallest scale, in metres (0 for none): a pull towards thin discs, as
    surfaces are. A blob that fits the source views from their side of the road shows a novel camera
    (another height, another angle) a smear; a disc on the surface shows it the surface."""
    if len(log_scales) == 0:
        return log_scales.sum()
    return torch.exp(log_scales.min(dim=1).values.clamp(LOG_SCALE_MIN, LOG_SCALE_MAX)).mean()


def psnr(pred: torch.Tensor, target: torch.Tensor, valid: torch.Tensor | None = None) -> float:
    """PSNR in dB of [0,1] images over valid pixels (inf for identical images)."""
    d = (pred.detach().clamp(0, 1) - target) ** 2
    mse = float(d.mean() if valid is None else d[valid].mean())
    return math.inf if mse <= 0 else -10.0 * math.log10(mse)
