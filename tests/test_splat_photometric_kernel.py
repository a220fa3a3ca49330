"""The fused numba photometric loss against its torch reference (``losses.photometric_loss``)."""

from __future__ import annotations

import pytest
import torch

from nuav2.splat._photometric import fused_photometric_loss
from nuav2.splat.losses import photometric_loss

TOL = {torch.float64: 1e-10, torch.float32: 1e-5}


def _images(h: int, w: int, dtype: torch.dtype, seed: int = 0, p_valid: float = 0.7):
    gen = torch.Generator().manual_seed(seed)
    pred = torch.rand(h, w, 3, generator=gen, dtype=torch.float64).to(dtype)
    target = torch.rand(h, w, 3, generator=gen, dtype=torch.float64).to(dtype)
    valid = torch.rand(h, w, generator=gen) < p_valid
    return pred, target, valid


def _both(pred, target, valid, lambda_ssim=0.2, scale=1.0):
    """(loss, l1, s, grad) of the reference and of the fused loss."""
    out = []
    for fn in (photometric_loss, fused_photometric_loss):
        p = pred.detach().clone().requires_grad_(True)
        loss, l1, s = fn(p, target, valid, lambda_ssim)
        (scale * loss).backward()
        out.append((loss.detach(), l1, s, p.grad))
    return out


def _assert_agree(ref, got, tol):
    (loss_r, l1_r, s_r, g_r), (loss_f, l1_f, s_f, g_f) = ref, got
    assert loss_f.dtype == loss_r.dtype and loss_f.shape == ()
    assert torch.isfinite(loss_f) and torch.isfinite(g_f).all()
    assert abs(float(loss_f) - float(loss_r)) <= tol * max(1.0, abs(float(loss_r)))
    assert abs(l1_f - l1_r) <= tol and abs(s_f - s_r) <= tol
    assert g_f.dtype == g_r.dtype and g_f.shape == g_r.shape
    # relative to the largest component, floored at the per-pixel weight 1/(3 n) for the cases
    # (pred == target) whose true gradient is 0 and both sides are rounding noise
    scale = max(float(g_r.abs().max()), 1.0 / g_r.numel())
    torch.testing.assert_close(g_f, g_r, rtol=0.0, atol=tol * scale)


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
@pytest.mark.parametrize("hw", [(1, 1), (3, 5), (10, 7), (11, 11), (17, 23), (40, 57)])
@pytest.mark.parametrize("masked", [True, False])
def test_matches_reference(dtype, hw, masked):
    pred, target, valid = _images(*hw, dtype, seed=hw[0] * 100 + hw[1])
    ref, got = _both(pred, target, valid if masked else None)
    _assert_agree(ref, got, TOL[dtype])


def test_matches_reference_parallel_float32():
    """Large enough for the parallel float32 path to run on every numba thread."""
    pred, target, valid = _images(130, 131, torch.float32, p_valid=0.95)
    ref, got = _both(pred, target, valid)
    _assert_agree(ref, got, TOL[torch.float32])


@pytest.mark.parametrize("lambda_ssim", [0.0, 0.2, 1.0])
def test_lambda_and_upstream_gradient(lambda_ssim):
    pred, target, valid = _images(9, 14, torch.float64, seed=3)
    ref, got = _both(pred, target, valid, lambda_ssim, scale=-2.5)
    _assert_agree(ref, got, TOL[torch.float64])


def test_gradcheck():
    # an unmasked image only: with a mask, the reference's target is pred.detach() at invalid pixels,
    # which finite differences see move but autograd (by design) does not
    gen = torch.Generator().manual_seed(7)
    pred = torch.rand(5, 6, 3, generator=gen, dtype=torch.float64)
    target = (pred + 0.1 + 0.5 * torch.rand(5, 6, 3, generator=gen, dtype=torch.float64)) % 1.0
    pred.requires_grad_(True)
    for valid in (None, torch.ones(5, 6, dtype=torch.bool)):
        fn = lambda p, v=valid: fused_photometric_loss(p, target, v, 0.3)[0]  # noqa: E731
        assert torch.autograd.gradcheck(fn, (pred,))


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_all_invalid_mask(dtype):
    pred, target, _ = _images(6, 13, dtype)
    valid = torch.zeros(6, 13, dtype=torch.bool)
    ref, got = _both(pred, target, valid)
    _assert_agree(ref, got, TOL[dtype])
    loss, l1, s, grad = got
    assert l1 == 0.0 and s == 0.0 and float(loss) == pytest.approx(0.2)
    assert (grad == 0).all()


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
@pytest.mark.parametrize("case", ["zeros", "ones", "half", "same", "binary", "tiny"])
def test_hard_cases_finite(dtype, case):
    h, w = (1, 1) if case == "tiny" else (12, 9)
    pred, target, valid = _images(h, w, dtype, seed=11)
    if case in ("zeros", "ones", "half"):
        value = {"zeros": 0.0, "ones": 1.0, "half": 0.5}[case]
        pred, target = torch.full_like(pred, value), torch.full_like(target, 1.0 - value)
    elif case == "same":
        target = pred.clone()
    elif case == "binary":
        pred, target = (pred > 0.5).to(dtype), (target > 0.5).to(dtype)
    for v in (valid, None, torch.zeros_like(valid)):
        ref, got = _both(pred, target, v)
        _assert_agree(ref, got, TOL[dtype])


def test_non_contiguous_inputs():
    pred, target, valid = _images(14, 19, torch.float32, seed=5)
    pred_t, target_t = pred.transpose(0, 1), target.transpose(0, 1)   # (19, 14, 3) views
    valid_t = valid.t()
    assert not pred_t.is_contiguous() and not valid_t.is_contiguous()
    ref, got = _both(pred_t, target_t, valid_t)
    _assert_agree(ref, got, TOL[torch.float32])


def test_no_grad_paths():
    pred, target, valid = _images(8, 8, torch.float32, seed=2)
    ref = photometric_loss(pred, target, valid)
    got = fused_photometric_loss(pred, target, valid)
    assert not got[0].requires_grad
    assert float(got[0]) == pytest.approx(float(ref[0]), rel=1e-6)
    with torch.no_grad():
        got = fused_photometric_loss(pred.clone().requires_grad_(True), target, valid)
    assert not got[0].requires_grad and float(got[0]) == pytest.approx(float(ref[0]), rel=1e-6)


def test_rejects_bad_inputs():
    img = torch.rand(4, 5, 3)
    bad = [
        (img.to(torch.float16), img.to(torch.float16), None),
        (img.to(torch.int32), img.to(torch.int32), None),
        (img, img.double(), None),
        (img[..., :2], img[..., :2], None),
        (img[0], img[0], None),
        (img, img[:3], None),
        (img[:0], img[:0], None),
        (img, img, torch.ones(4, 5)),
        (img, img, torch.ones(5, 4, dtype=torch.bool)),
        (img.to("meta"), img.to("meta"), None),
        (img, img.clone().requires_grad_(True), None),
    ]
    for pred, target, valid in bad:
        with pytest.raises(ValueError, match="fused_photometric_loss"):
            fused_photometric_loss(pred, target, valid)
