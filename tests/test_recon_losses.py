"""Training losses: SSIM oracle values, masking, depth trimming, sky BCE, PSNR."""

from __future__ import annotations

import math

import numpy as np
import torch

from nuav2.splat.losses import SSIM_C1, depth_loss, flatness_loss, photometric_loss, psnr, sky_loss, ssim_map


def test_ssim_identical_is_one_and_constant_images_match_formula():
    rng = np.random.default_rng(0)
    x = torch.tensor(rng.uniform(size=(24, 30, 3)), dtype=torch.float64)
    np.testing.assert_allclose(ssim_map(x, x).numpy(), 1.0, atol=1e-9)
    a, b = 0.2, 0.7
    xa, xb = torch.full((24, 30, 3), a, dtype=torch.float64), torch.full((24, 30, 3), b, dtype=torch.float64)
    # Away from the zero-padded border the local stats are exact: var = cov = 0.
    expect = (2 * a * b + SSIM_C1) / (a * a + b * b + SSIM_C1)
    np.testing.assert_allclose(ssim_map(xa, xb)[8:-8, 8:-8].numpy(), expect, rtol=1e-9)


def test_ssim_drops_with_noise():
    rng = np.random.default_rng(1)
    x = torch.tensor(rng.uniform(size=(32, 32, 3)), dtype=torch.float32)
    noisy = (x + 0.2 * torch.tensor(rng.normal(size=x.shape), dtype=torch.float32)).clamp(0, 1)
    assert float(ssim_map(x, noisy).mean()) < 0.9


def test_photometric_ignores_masked_pixels():
    rng = np.random.default_rng(2)
    pred = torch.tensor(rng.uniform(size=(20, 20, 3)), dtype=torch.float32, requires_grad=True)
    target = torch.tensor(rng.uniform(size=(20, 20, 3)), dtype=torch.float32)
    valid = torch.ones(20, 20, dtype=torch.bool)
    valid[12:, 12:] = False
    loss_a, _, _ = photometric_loss(pred, target, valid)
    target_b = target.clone()
    target_b[12:, 12:] = 1.0 - target_b[12:, 12:]  # change only the masked region
    loss_b, _, _ = photometric_loss(pred, target_b, valid)
    assert abs(float(loss_a.detach()) - float(loss_b.detach())) < 1e-6
    loss_a.backward()
    assert torch.isfinite(pred.grad).all()
    # Pixels far inside the mask get no photometric gradient at all.
    assert float(pred.grad[17:, 17:].abs().max()) == 0.0
    same, l1, s = photometric_loss(target, target, valid)
    assert float(same) < 1e-6 and l1 == 0.0 and abs(s - 1.0) < 1e-6


def test_the_photo_behind_the_mask_stops_every_gradient_to_masked_pixels():
    """The ego body's edge: masking the loss still leaves SSIM's gradient on masked pixels next to it (what
    turned the road behind a waiting ego see-through); the photo behind the mask leaves none, in both the
    reference loss and the fused one training uses."""
    from nuav2.splat._photometric import fused_photometric_loss
    from nuav2.splat.losses import photo_behind_mask

    rng = np.random.default_rng(3)
    target = torch.tensor(rng.uniform(size=(24, 24, 3)), dtype=torch.float32)
    valid = torch.ones(24, 24, dtype=torch.bool)
    valid[16:] = False  # the ego body along the bottom
    for loss_fn in (photometric_loss, fused_photometric_loss):
        pred = torch.tensor(rng.uniform(size=(24, 24, 3)), dtype=torch.float32, requires_grad=True)
        loss_fn(pred, target, valid)[0].backward()
        assert float(pred.grad[16:18].abs().max()) > 0  # the masked loss alone: SSIM reaches past the edge
        pred.grad = None
        loss, _, _ = loss_fn(photo_behind_mask(pred, target, valid), target, valid)
        loss.backward()
        assert float(pred.grad[16:].abs().max()) == 0.0 and float(pred.grad[:16].abs().max()) > 0
        plain, _, _ = loss_fn(pred.detach(), target, valid)
        assert abs(loss.item() - plain.item()) < 0.05  # valid pixels scored as before (but SSIM at the edge)


def test_depth_loss_zero_when_matching_and_trims_outliers():
    h, w = 10, 12
    depth = torch.full((h, w), 5.0)
    alpha = torch.ones(h, w)
    uvz = torch.tensor([[1.0, 1.0, 5.0], [3.2, 4.9, 5.0], [10.6, 8.4, 5.0]])
    assert float(depth_loss(depth, alpha, uvz)) == 0.0
    depth2 = depth.clone()
    depth2[2, 5] = 50.0  # one wild sample among 20: trimmed by the 95 % rule
    rows = [[c, 2.0, 5.0] for c in range(w)] + [[c, 6.0, 5.0] for c in range(8)]
    uvz20 = torch.tensor(rows, dtype=torch.float32)
    assert float(depth_loss(depth2, alpha, uvz20, trim=0.95)) == 0.0
    assert float(depth_loss(depth2, alpha, uvz20, trim=1.0)) > 0.4
    # Uncovered pixels (alpha below 0.5) do not count; no samples -> 0 with a graph.
    assert float(depth_loss(depth2, torch.zeros(h, w), uvz20)) == 0.0
    assert float(depth_loss(depth, alpha, torch.zeros(0, 3))) == 0.0


def test_depth_loss_relative_error_value():
    depth = torch.full((4, 4), 11.0, requires_grad=True)
    loss = depth_loss(depth, torch.ones(4, 4), torch.tensor([[1.0, 1.0, 10.0]]), trim=1.0)
    np.testing.assert_allclose(float(loss.detach()), 0.1, rtol=1e-6)
    loss.backward()
    assert float(depth.grad[1, 1]) > 0


def test_sky_loss():
    alpha = torch.full((6, 6), 0.5)
    sky = torch.zeros(6, 6, dtype=torch.bool)
    assert float(sky_loss(alpha, sky)) == 0.0
    sky[:2] = True
    np.testing.assert_allclose(float(sky_loss(alpha, sky)), -math.log(0.5), rtol=1e-6)
    assert float(sky_loss(torch.zeros(6, 6), sky)) < 1e-3
    assert math.isfinite(float(sky_loss(torch.ones(6, 6), sky)))  # alpha = 1 is clamped, not inf


def test_psnr_known_value():
    a = torch.zeros(8, 8, 3)
    b = torch.full((8, 8, 3), 0.1)
    np.testing.assert_allclose(psnr(a, b), 20.0, rtol=1e-5)
    assert psnr(a, a) == math.inf
    valid = torch.zeros(8, 8, dtype=torch.bool)
    valid[0, 0] = True
    c = b.clone()
    c[1:] = 1.0
    np.testing.assert_allclose(psnr(a, c, valid), 20.0, rtol=1e-5)


def test_separable_ssim_equals_2d_window():
    """Oracle: the textbook 2D Gaussian-window SSIM (one 11x11 conv per moment)."""
    import torch.nn.functional as F

    rng = np.random.default_rng(3)
    x = torch.tensor(rng.uniform(size=(30, 41, 3)))
    y = torch.tensor(rng.uniform(size=(30, 41, 3)))
    t = torch.arange(11, dtype=torch.float64) - 5
    g = torch.exp(-(t**2) / (2 * 1.5**2))
    g = g / g.sum()
    w = (g[:, None] * g[None, :])[None, None].expand(3, 1, 11, 11)

    def f(img: torch.Tensor) -> torch.Tensor:
        return F.conv2d(img, w, padding=5, groups=3)

    a, b = x.permute(2, 0, 1)[None], y.permute(2, 0, 1)[None]
    ma, mb = f(a), f(b)
    va, vb, c = f(a * a) - ma**2, f(b * b) - mb**2, f(a * b) - ma * mb
    ref = ((2 * ma * mb + 1e-4) * (2 * c + 9e-4) / ((ma**2 + mb**2 + 1e-4) * (va + vb + 9e-4)))[0].mean(0)
    np.testing.assert_allclose(ssim_map(x, y).numpy(), ref.numpy(), atol=1e-12)


def test_flatness_loss_is_the_mean_smallest_scale_and_pulls_on_that_axis_only():
    scales = torch.tensor([[0.5, 0.02, 0.3], [0.1, 0.2, 0.4]], dtype=torch.float64)
    log_scales = torch.log(scales).requires_grad_()
    loss = flatness_loss(log_scales)
    assert math.isclose(loss.item(), (0.02 + 0.1) / 2, rel_tol=1e-12)
    loss.backward()
    grad = log_scales.grad.numpy()
    # d/d log s of s/2 is s/2, on each row's smallest axis alone
    np.testing.assert_allclose(grad, [[0.0, 0.01, 0.0], [0.05, 0.0, 0.0]], atol=1e-15)


def test_flatness_loss_of_no_gaussians_is_zero_not_nan():
    empty = torch.zeros((0, 3), requires_grad=True)
    loss = flatness_loss(empty)
    loss.backward()
    assert loss.item() == 0.0 and empty.grad is not None and empty.grad.shape == (0, 3)
