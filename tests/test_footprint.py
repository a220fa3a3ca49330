"""Rendering above the training resolution keeps each Gaussian's trained angular footprint
(nuav2.splat.footprint), checked against the dense reference projection."""

from __future__ import annotations

import numpy as np
import torch

from nuav2.splat.constants import EPS2D
from nuav2.splat.dense_reference import project_dense
from nuav2.splat.footprint import focal_px, widen_to_training_footprint

F_TRAIN = 220.0


def K_of(f: float, w: int, h: int) -> np.ndarray:
    return np.array([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1]], np.float64)


def angular_cov(means, quats, log_scales, K, w, h) -> torch.Tensor:
    """Each Gaussian's projected 2D covariance (with the rasterizer's blur) in radians² (over focal²)."""
    n = len(means)
    _, conics, _, _, visible = project_dense(means, quats, log_scales, torch.ones(n), np.eye(4), K, w, h,
                                             0.1, 1000.0, 0.0)
    assert bool(visible.all())
    a, b, c = conics.unbind(-1)
    det = a * c - b * b
    cov = torch.stack([c / det, -b / det, a / det], -1)  # the conic's inverse
    return cov / float(K[0, 0]) ** 2


def gaussians(n: int = 200, seed: int = 0, off_axis: float = 0.0):
    g = torch.Generator().manual_seed(seed)
    z = 2.0 + 48.0 * torch.rand(n, generator=g, dtype=torch.float64)
    xy = off_axis * z[:, None] * (2 * torch.rand(n, 2, generator=g, dtype=torch.float64) - 1)
    means = torch.cat([xy, z[:, None]], 1)
    quats = torch.nn.functional.normalize(torch.randn(n, 4, generator=g, dtype=torch.float64), dim=1)
    exponent = -3.0 + 3.0 * torch.rand(n, 3, generator=g, dtype=torch.float64)
    log_scales = torch.log(10**exponent)  # 1 mm to 1 m
    return means, quats, log_scales


def test_the_widened_gaussian_has_its_training_footprint_on_the_optical_axis():
    """On the axis the projected covariance at 4x the training focal, widened, equals (in radians) the one
    the training camera saw, blur included, for any shape and orientation; unwidened, small ones shrink."""
    means, quats, log_scales = gaussians()
    means[:, :2] = 0.0
    trained = angular_cov(means, quats, log_scales, K_of(F_TRAIN, 512, 512), 512, 512)
    K_t = K_of(4 * F_TRAIN, 2048, 2048)
    widened = widen_to_training_footprint(log_scales, means, np.eye(4), focal_px(K_t), F_TRAIN)
    ours = angular_cov(means, quats, widened, K_t, 2048, 2048)
    rel = ((ours - trained).abs() / trained[:, [0, 2]].max(1, keepdim=True).values).max()
    assert float(rel) < 1e-6
    plain = angular_cov(means, quats, log_scales, K_t, 2048, 2048)
    assert float((plain[:, 0] / trained[:, 0]).min()) < 0.2  # without it a sub-pixel Gaussian is 5x smaller


def test_off_axis_the_footprint_is_kept_within_the_perspective_stretch():
    """Off the axis (to 32 degrees, a nuScenes camera's edge) an isotropic 3D variance projects stretched by
    up to 1 + tan^2 of the angle: the widened footprint lies between the trained one and that stretch."""
    means, quats, log_scales = gaussians(off_axis=0.62)
    trained = angular_cov(means, quats, log_scales, K_of(F_TRAIN, 512, 512), 512, 512)
    K_t = K_of(4 * F_TRAIN, 2048, 2048)
    ours = angular_cov(means, quats, widen_to_training_footprint(log_scales, means, np.eye(4), focal_px(K_t),
                                                                 F_TRAIN), K_t, 2048, 2048)
    for i in (0, 2):
        ratio = ours[:, i] / trained[:, i]
        assert float(ratio.min()) > 0.999 and float(ratio.max()) < 1.0 + 2 * 0.62**2


def test_at_or_below_the_training_resolution_nothing_changes_and_nothing_overflows():
    means, quats, log_scales = gaussians()
    for f in (F_TRAIN / 2, F_TRAIN):
        assert widen_to_training_footprint(log_scales, means, np.eye(4), f, F_TRAIN) is log_scales
    assert widen_to_training_footprint(log_scales, means, np.eye(4), 5 * F_TRAIN, None) is log_scales
    huge = torch.full((3, 3), 80.0, dtype=torch.float64)  # exp(2 x 80) overflows float32 and nearly float64
    pts = torch.tensor([[0.0, 0.0, 1e-6], [0.0, 0.0, 5.0], [1.0, 2.0, 1e4]], dtype=torch.float64)
    out = widen_to_training_footprint(huge.float(), pts.float(), np.eye(4), 6 * F_TRAIN, F_TRAIN)
    assert torch.isfinite(out).all() and torch.allclose(out, huge.float())
    tiny = torch.full((3, 3), -30.0)
    out = widen_to_training_footprint(tiny, pts.float(), np.eye(4), 6 * F_TRAIN, F_TRAIN)
    assert torch.isfinite(out).all() and bool((out > -30.0).all())
    blur = EPS2D * (1 / F_TRAIN**2 - 1 / (6 * F_TRAIN) ** 2)
    assert abs(float(out[1, 0]) - 0.5 * np.log(blur * 25.0)) < 1e-5  # a 5 m deep speck: the blur alone
