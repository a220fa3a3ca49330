"""PSNR and SSIM: hand values, an independent scipy SSIM oracle, layouts, gradients, regions, bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.ndimage import gaussian_filter

from nuav2.evaluate.image_metrics import gaussian_window_1d, psnr, region_metrics, ssim, ssim_map, ssim_torch


def scipy_ssim(a: np.ndarray, b: np.ndarray, data_range: float) -> float:
    """Wang et al. SSIM of 2-D float64 images with scipy's Gaussian filter, cropped to valid windows."""
    return float(scipy_ssim_map(a, b, data_range).mean())


def scipy_ssim_map(a: np.ndarray, b: np.ndarray, data_range: float) -> np.ndarray:
    """The per-pixel SSIM map behind :func:`scipy_ssim` (valid window centres only)."""

    def blur(x):  # sigma 1.5 truncated at 3.5 sigma -> radius 5 -> an 11-tap window
        return gaussian_filter(x, sigma=1.5, truncate=3.5)

    c1, c2 = (0.01 * data_range) ** 2, (0.03 * data_range) ** 2
    mu_a, mu_b = blur(a), blur(b)
    var_a, var_b, cov = blur(a * a) - mu_a**2, blur(b * b) - mu_b**2, blur(a * b) - mu_a * mu_b
    s = ((2 * mu_a * mu_b + c1) * (2 * cov + c2)) / ((mu_a**2 + mu_b**2 + c1) * (var_a + var_b + c2))
    return s[5:-5, 5:-5]


def test_window_is_normalised_gaussian():
    w = gaussian_window_1d()
    assert w.shape == (11,) and float(w.sum()) == pytest.approx(1.0, abs=1e-15)
    assert float(w[5] / w[6]) == pytest.approx(math.exp(0.5 / 1.5**2))


def test_psnr_hand_values():
    a = np.zeros((8, 8, 3))
    assert psnr(a, a + 0.1) == pytest.approx(20.0, abs=1e-9)  # mse 0.01
    assert psnr(a, a + 25.5, data_range=255.0) == pytest.approx(20.0, abs=1e-9)
    assert psnr(a, a) == 100.0  # capped instead of +inf
    b = a.copy()
    b[:4] = 0.5  # masked to the untouched half the images are identical
    mask = np.zeros((8, 8), dtype=bool)
    mask[4:] = True
    assert psnr(a, b, mask=mask) == 100.0
    assert psnr(a, b) == pytest.approx(10 * math.log10(1 / (0.25 / 2)))


def test_ssim_matches_scipy_oracle_and_layouts():
    rng = np.random.default_rng(0)
    a = rng.uniform(0, 1, (40, 33, 3))
    b = np.clip(a + rng.normal(0, 0.1, a.shape), 0, 1)
    want = np.mean([scipy_ssim(a[..., c], b[..., c], 1.0) for c in range(3)])
    assert ssim(a, b) == pytest.approx(want, abs=1e-12)
    assert ssim(np.moveaxis(a, -1, 0), np.moveaxis(b, -1, 0), channel_axis=0) == pytest.approx(
        want, abs=1e-12
    )
    assert ssim(torch.from_numpy(a), torch.from_numpy(b)) == pytest.approx(want, abs=1e-12)
    assert ssim(a[..., 0] * 255, b[..., 0] * 255, data_range=255.0) == pytest.approx(
        scipy_ssim(a[..., 0], b[..., 0], 1.0), abs=1e-12
    )
    batch = torch.from_numpy(np.stack([a, b])).permute(0, 3, 1, 2).float()
    per_image = ssim_torch(batch, batch.flip(0), reduction="none")
    assert per_image.shape == (2,) and per_image.dtype == torch.float32
    assert float(per_image[0]) == pytest.approx(want, abs=1e-5)


def test_region_metrics_against_the_scipy_map_and_hand_psnr():
    rng = np.random.default_rng(3)
    truth = rng.uniform(0, 255, (30, 40, 3))
    img = truth.copy()
    img[:12] += rng.normal(0, 20, img[:12].shape)  # error only in the top rows ("sky")
    sky = np.zeros((30, 40), bool)
    sky[:12] = True
    tiny = np.zeros((30, 40), bool)
    tiny[20, 20:25] = True
    got = region_metrics(img, truth, {"whole": np.ones_like(sky), "sky": sky, "ground": ~sky, "tiny": tiny},
                         data_range=255.0)
    assert got["ground"]["psnr_db"] == 100.0 and got["ground"]["pixels"] == 18 * 40
    err = (img - truth)[:12]
    assert got["sky"]["psnr_db"] == pytest.approx(10 * math.log10(255.0**2 / np.mean(err**2)), abs=1e-9)
    assert got["whole"]["psnr_db"] == pytest.approx(psnr(img, truth, data_range=255.0), abs=1e-12)
    assert got["whole"]["ssim"] == pytest.approx(ssim(img, truth, data_range=255.0), abs=1e-12)
    oracle = np.mean([scipy_ssim_map(img[..., c] / 255, truth[..., c] / 255, 1.0) for c in range(3)], axis=0)
    assert got["sky"]["ssim"] == pytest.approx(oracle[sky[5:-5, 5:-5]].mean(), abs=1e-12)
    assert got["ground"]["ssim"] < 1.0  # windows centred on the ground near the border see the sky's error
    assert got["tiny"] is None  # 5 pixels: too few to score
    assert ssim_map(img, truth, 255.0).shape == (20, 30)
    with pytest.raises(ValueError, match="mask shape"):
        region_metrics(img, truth, {"bad": sky[:5]})


def test_ssim_hand_cases():
    rng = np.random.default_rng(1)
    a = rng.uniform(0, 1, (20, 20))
    assert ssim(a, a) == pytest.approx(1.0, abs=1e-12)
    assert ssim(a, 1 - a) < 0  # anti-correlated structure
    flat = np.full((16, 16), 0.5)
    assert ssim(flat, flat) == pytest.approx(1.0, abs=1e-12)  # the constants keep 0/0 away
    assert ssim(a, 0.5 * a) == pytest.approx(ssim(0.5 * a, a), abs=1e-12)  # symmetric


def test_ssim_is_differentiable():
    rng = np.random.default_rng(2)
    target = torch.from_numpy(rng.uniform(0, 1, (1, 3, 16, 16)))
    x = (target + 0.2 * torch.from_numpy(rng.normal(0, 1, target.shape))).requires_grad_(True)
    loss = 1 - ssim_torch(x, target)
    loss.backward()
    assert x.grad is not None and torch.isfinite(x.grad).all() and float(x.grad.abs().sum()) > 0
    with torch.no_grad():  # a small step against the gradient improves SSIM
        better = 1 - ssim_torch(x - 1e-3 * x.grad / x.grad.norm(), target)
    assert float(better) < float(loss.detach())


def test_bad_inputs():
    a = np.zeros((16, 16))
    with pytest.raises(ValueError, match="shapes differ"):
        psnr(a, np.zeros((16, 15)))
    with pytest.raises(ValueError, match="NaN or Inf"):
        ssim(a, np.full((16, 16), np.nan))
    with pytest.raises(ValueError, match="at least 11x11"):
        ssim(np.zeros((8, 16)), np.zeros((8, 16)))
    with pytest.raises(ValueError, match="mask selects no pixels"):
        psnr(a, a, mask=np.zeros((16, 16), dtype=bool))
    with pytest.raises(ValueError, match="channel_axis"):
        ssim(np.zeros((16, 16, 3)), np.zeros((16, 16, 3)), channel_axis=None)
