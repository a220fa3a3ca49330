"""Backward pass: float64 gradcheck of the custom autograd Functions and agreement with the dense
reference's autograd gradients for every Gaussian parameter."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from raster_scenes import PARAMS, grads_of, leaves, max_rel, pinhole, random_gaussians, random_pose

from nuav2.splat import rasterize
from nuav2.splat.dense_reference import rasterize_dense

W, H = 70, 50


def _tiny_scene(n: int, seed: int, sh_degree=None):
    """A few well-separated, mid-opacity Gaussians (no pixel sits on an alpha threshold)."""
    params = random_gaussians(n, seed, dtype=torch.float64, depth=(3.0, 5.0), half_fov=0.35,
                              log_scale=(-1.6, -1.2), sh_degree=sh_degree)
    params["opacity_logits"] = torch.linspace(-0.5, 1.0, n, dtype=torch.float64)
    return params


def _images(*p, K, w, h, **kw):
    out = rasterize(*p, np.eye(4), K, w, h, **kw)
    return out.rgb, out.alpha, out.depth


def test_gradcheck_float64_all_parameters():
    w, h = 18, 6                                    # two tiles, the second partial; 540 outputs
    params = _tiny_scene(3, 0)
    K = pinhole(w, h, f=9.0)
    assert torch.autograd.gradcheck(lambda *p: _images(*p, K=K, w=w, h=h, background=torch.tensor(
        [0.1, 0.2, 0.3], dtype=torch.float64)), tuple(leaves(params)), eps=1e-6, atol=1e-6, rtol=1e-4)


def test_gradcheck_float64_sh_and_batch():
    w, h = 24, 18
    params = _tiny_scene(4, 1, sh_degree=1)
    poses = np.stack([np.eye(4), np.eye(4)])
    poses[1, :3, 3] = [0.15, -0.1, 0.2]
    K = pinhole(w, h, f=18.0)

    def images(*p):
        out = rasterize(*p, poses, K, w, h)
        return out.rgb, out.alpha, out.depth

    assert torch.autograd.gradcheck(images, tuple(leaves(params)), eps=1e-6, atol=1e-6, rtol=1e-4,
                                    fast_mode=True)


@pytest.mark.parametrize("seed", [0, 1])
def test_gradients_match_dense_reference_float32(seed):
    pose = random_pose(seed + 20)
    params = random_gaussians(400, seed, pose)
    K = pinhole(W, H)
    bg = torch.tensor([0.3, 0.3, 0.3])
    _, g_kernel = grads_of(rasterize, params, pose, K, W, H, near=0.2, background=bg)
    _, g_dense = grads_of(rasterize_dense, params, pose, K, W, H, near=0.2, background=bg)
    for name, a, b in zip(PARAMS, g_kernel, g_dense):
        assert torch.isfinite(a).all(), name
        assert b.abs().max() > 0, f"{name}: the reference gradient vanished, the test proves nothing"
        assert max_rel(a, b) < 1e-3, f"{name}: relative error {max_rel(a, b):.2e}"


def test_gradients_match_dense_reference_float64_sh():
    pose = random_pose(5)
    params = random_gaussians(250, 5, pose, dtype=torch.float64, sh_degree=3)
    K = pinhole(W, H)
    _, g_kernel = grads_of(rasterize, params, pose, K, W, H)
    _, g_dense = grads_of(rasterize_dense, params, pose, K, W, H)
    for name, a, b in zip(PARAMS, g_kernel, g_dense):
        assert max_rel(a, b) < 1e-10, f"{name}: relative error {max_rel(a, b):.2e}"


def test_means2d_gradient_and_absgrad_for_densification():
    pose = random_pose(9)
    params = random_gaussians(300, 9, pose)
    params["means"][:20] = params["means"][:20] - 100.0 * torch.tensor(pose[:3, 2], dtype=torch.float32)
    out = rasterize(*leaves(params), pose, pinhole(W, H), W, H)
    means2d = out.meta["means2d"]
    means2d.retain_grad()
    out.rgb.sum().backward()
    grad, absgrad = means2d.grad[0], means2d.absgrad[0]
    visible = out.meta["visible"][0]
    assert not visible[:20].any(), "Gaussians moved behind the camera must be culled"
    assert (grad[~visible] == 0).all() and (absgrad[~visible] == 0).all()
    assert (grad[visible].abs().sum(-1) > 0).float().mean() > 0.5
    # sum_i |g_i| >= |sum_i g_i| per Gaussian and axis
    assert (absgrad + 1e-6 >= grad.abs()).all()
    assert (absgrad > grad.abs() + 1e-6).any(), "pixel gradients of mixed sign should make absgrad larger"


def test_batched_gradient_is_sum_of_single_camera_gradients():
    poses = np.stack([random_pose(s) for s in (30, 31)])
    params = random_gaussians(200, 30, poses[0], dtype=torch.float64)
    K = pinhole(W, H)
    ts = leaves(params)
    rasterize(*ts, poses, K, W, H).rgb.sum().backward()
    batched = [t.grad.clone() for t in ts]
    summed = [torch.zeros_like(t) for t in ts]
    for c in range(2):
        ts = leaves(params)
        rasterize(*ts, poses[c], K, W, H).rgb.sum().backward()
        summed = [s + t.grad for s, t in zip(summed, ts)]
    for name, a, b in zip(PARAMS, batched, summed):
        assert max_rel(a, b) < 1e-12, name
