"""Image reconstruction metrics: PSNR and SSIM (Wang et al. 2004), for numpy arrays or torch tensors,
over whole images or per region (ground, objects, sky: :func:`region_metrics`).

SSIM uses the standard settings: an 11 x 11 Gaussian window with sigma 1.5 (normalised),
K1 = 0.01, K2 = 0.03, population (not sample) covariances, and only the "valid" window
positions (no padding), averaged over pixels and channels. This equals scikit-image's
``structural_similarity(gaussian_weights=True, sigma=1.5, use_sample_covariance=False)``.
:func:`ssim_torch` is differentiable, so the splat trainer can use ``1 - ssim`` as a loss.
"""

from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F

WINDOW_SIZE = 11
WINDOW_SIGMA = 1.5
K1, K2 = 0.01, 0.03


def gaussian_window_1d(
    size: int = WINDOW_SIZE, sigma: float = WINDOW_SIGMA, dtype: torch.dtype = torch.float64
) -> torch.Tensor:
    """Normalised 1-D Gaussian taps; SSIM's 2-D window is their outer product (separable)."""
    x = torch.arange(size, dtype=torch.float64) - (size - 1) / 2
    w = torch.exp(-0.5 * (x / sigma) ** 2)
    return (w / w.sum()).to(dtype)


def _check_pair(a, b, what: str) -> None:
    if tuple(a.shape) != tuple(b.shape):
        raise ValueError(f"{what}: image shapes differ: {tuple(a.shape)} vs {tuple(b.shape)}")
    for name, x in (("first", a), ("second", b)):
        finite = torch.isfinite(x).all() if isinstance(x, torch.Tensor) else np.isfinite(x).all()
        if not bool(finite):
            raise ValueError(f"{what}: the {name} image contains NaN or Inf")


def _to_tensor(x) -> torch.Tensor:
    if isinstance(x, torch.Tensor):
        return x if x.is_floating_point() else x.double()
    return torch.from_numpy(np.ascontiguousarray(x, dtype=np.float64))


def psnr(a, b, data_range: float = 1.0, max_db: float = 100.0, mask=None) -> float:
    """Peak signal-to-noise ratio in dB over all elements (or the pixels where ``mask`` is true).

    Identical images would give +inf; the result is capped at ``max_db`` so means over frames
    stay finite. ``mask`` has the image's shape or its leading (H, W) shape.
    """
    _check_pair(a, b, "psnr")
    if data_range <= 0:
        raise ValueError(f"psnr: data_range must be > 0, got {data_range}")
    ta, tb = _to_tensor(a).double(), _to_tensor(b).double()
    err = (ta - tb) ** 2
    if mask is not None:
        m = _to_tensor(mask).bool() if not isinstance(mask, torch.Tensor) else mask.bool()
        m = m.to(err.device)
        while m.ndim < err.ndim:
            m = m.unsqueeze(-1)
        m = m.expand_as(err)
        if not bool(m.any()):
            raise ValueError("psnr: the mask selects no pixels")
        err = err[m]
    mse = float(err.mean())
    floor = data_range**2 * 10.0 ** (-max_db / 10.0)
    return 10.0 * math.log10(data_range**2 / max(mse, floor))


def ssim_torch(
    a: torch.Tensor, b: torch.Tensor, data_range: float = 1.0, reduction: str = "mean"
) -> torch.Tensor:
    """SSIM of (N, C, H, W) tensors; ``reduction`` "mean" -> scalar, "none" -> (N,) per image."""
    if a.ndim != 4:
        raise ValueError(f"ssim_torch: expected (N, C, H, W) tensors, got shape {tuple(a.shape)}")
    _check_pair(a, b, "ssim_torch")
    if min(a.shape[-2:]) < WINDOW_SIZE:
        raise ValueError(
            f"ssim_torch: images must be at least {WINDOW_SIZE}x{WINDOW_SIZE}, got {tuple(a.shape[-2:])}"
        )
    if data_range <= 0:
        raise ValueError(f"ssim_torch: data_range must be > 0, got {data_range}")
    n, c = a.shape[:2]
    w = gaussian_window_1d(dtype=a.dtype).to(a.device)
    w_row = w.view(1, 1, 1, -1).expand(c, 1, 1, WINDOW_SIZE)
    w_col = w.view(1, 1, -1, 1).expand(c, 1, WINDOW_SIZE, 1)

    def blur(x: torch.Tensor) -> torch.Tensor:
        return F.conv2d(F.conv2d(x, w_row, groups=c), w_col, groups=c)

    c1, c2 = (K1 * data_range) ** 2, (K2 * data_range) ** 2
    mu_a, mu_b = blur(a), blur(b)
    var_a = blur(a * a) - mu_a**2
    var_b = blur(b * b) - mu_b**2
    cov = blur(a * b) - mu_a * mu_b
    ssim_map = ((2 * mu_a * mu_b + c1) * (2 * cov + c2)) / ((mu_a**2 + mu_b**2 + c1) * (var_a + var_b + c2))
    per_image = ssim_map.flatten(1).mean(dim=1)
    if reduction == "none":
        return per_image
    if reduction == "mean":
        return per_image.mean()
    raise ValueError(f"ssim_torch: reduction must be 'mean' or 'none', got {reduction!r}")


def ssim_map(a, b, data_range: float = 1.0, channel_axis: int | None = -1) -> np.ndarray:
    """Per-pixel SSIM, averaged over channels, at the valid window centres: float64 (H - 10, W - 10).

    Images as for :func:`ssim`; pixel (i, j) of the map is the window centred on image pixel
    (i + 5, j + 5). Computed with OpenCV's separable filter (torch's float64 grouped conv2d is
    ~100x slower on CPU); same maths as :func:`ssim_torch`.
    """
    import cv2

    _check_pair(a, b, "ssim")
    if data_range <= 0:
        raise ValueError(f"ssim: data_range must be > 0, got {data_range}")
    na = a.detach().cpu().double().numpy() if isinstance(a, torch.Tensor) else np.asarray(a, np.float64)
    nb = b.detach().cpu().double().numpy() if isinstance(b, torch.Tensor) else np.asarray(b, np.float64)
    if na.ndim == 2:
        na, nb = na[None], nb[None]
    elif na.ndim == 3:
        if channel_axis is None:
            raise ValueError("ssim: a 3-D image needs channel_axis")
        na, nb = np.moveaxis(na, channel_axis, 0), np.moveaxis(nb, channel_axis, 0)
    else:
        raise ValueError(f"ssim: expected a 2-D or 3-D image, got shape {na.shape}")
    if min(na.shape[-2:]) < WINDOW_SIZE:
        raise ValueError(f"ssim: images must be at least {WINDOW_SIZE}x{WINDOW_SIZE}, got {na.shape[-2:]}")
    w = gaussian_window_1d().numpy()
    r = WINDOW_SIZE // 2

    def blur(x: np.ndarray) -> np.ndarray:
        return cv2.sepFilter2D(np.ascontiguousarray(x), cv2.CV_64F, w, w, borderType=cv2.BORDER_CONSTANT)[
            r:-r, r:-r]

    c1, c2 = (K1 * data_range) ** 2, (K2 * data_range) ** 2
    total = np.zeros((na.shape[1] - 2 * r, na.shape[2] - 2 * r))
    for x, y in zip(na, nb):
        mu_a, mu_b = blur(x), blur(y)
        var_a = blur(x * x) - mu_a**2
        var_b = blur(y * y) - mu_b**2
        cov = blur(x * y) - mu_a * mu_b
        total += ((2 * mu_a * mu_b + c1) * (2 * cov + c2)) / ((mu_a**2 + mu_b**2 + c1) * (var_a + var_b + c2))
    return total / len(na)


def ssim(a, b, data_range: float = 1.0, channel_axis: int | None = -1) -> float:
    """SSIM of two images given as numpy arrays or tensors: (H, W), or with a channel axis.

    ``channel_axis`` names the channel axis of a 3-D image (default last: (H, W, C));
    use ``channel_axis=0`` for (C, H, W).
    """
    return float(ssim_map(a, b, data_range, channel_axis).mean())


def region_metrics(a, b, masks: dict[str, np.ndarray], data_range: float = 1.0,
                   min_pixels: int = 64) -> dict[str, dict | None]:
    """PSNR and SSIM of (H, W, C) images over each region of ``masks`` ({name: bool (H, W)}).

    A region's SSIM is the mean of the SSIM map over the region's pixels that are valid window
    centres (windows may reach across the region's border: the structure around a pixel counts).
    A region with fewer than ``min_pixels`` pixels (or valid centres) gets None: too few to say.
    """
    smap = ssim_map(a, b, data_range)
    r = WINDOW_SIZE // 2
    out: dict[str, dict | None] = {}
    for name, mask in masks.items():
        mask = np.asarray(mask, bool)
        if mask.shape != tuple(a.shape[:2]):
            raise ValueError(f"region {name!r}: mask shape {mask.shape} does not match the image "
                             f"{tuple(a.shape[:2])}")
        inner = mask[r:-r, r:-r]
        n = int(mask.sum())
        if n < min_pixels or int(inner.sum()) < min_pixels:
            out[name] = None
            continue
        out[name] = {"psnr_db": psnr(a, b, data_range=data_range, mask=mask),
                     "ssim": float(smap[inner].mean()), "pixels": n}
    return out
