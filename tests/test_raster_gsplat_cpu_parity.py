"""Our rasterizer against gsplat's own PyTorch rendering path on the CPU (runs in every CI job).

gsplat's torch path (with the CPU glue of nuav2.splat.gsplat_reference) applies gsplat's
conventions: quaternion order and normalisation, covariance R S S^T R^T, the EWA Jacobian with
its FoV clamp, the 0.3 px dilation, alpha = min(0.999, o e^-sigma) skipped below 1/255, the
T <= 1e-4 stop, background and expected depth. Matching it on random scenes in float64 to
rounding error checks every one of them; the mutation test shows the comparison would catch a
wrong one.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from raster_scenes import PARAMS, leaves, max_rel, pinhole, random_gaussians, random_pose, weighted_loss

from nuav2.splat import rasterize
from nuav2.splat.gsplat_reference import gsplat_installed, rasterize_gsplat_torch

pytestmark = pytest.mark.skipif(not gsplat_installed(),
                                reason="gsplat is not installed (pip install -e '.[dev]' brings it)")

W, H = 64, 48
NEAR = 0.2


class _Images:
    def __init__(self, rgb, alpha, depth):
        self.rgb, self.alpha, self.depth = rgb, alpha, depth


def _both(params, poses, K, **kw):
    """(ours, gsplat's) outputs and parameter gradients of the same weighted loss."""
    ours, ref = leaves(params), leaves(params)
    out = rasterize(*ours, poses, K, W, H, near=NEAR, **kw)
    rgb, alpha, depth, meta = rasterize_gsplat_torch(*ref, poses, K, W, H, near=NEAR, **kw)
    gs = _Images(rgb, alpha, depth)
    weighted_loss(out).backward()
    weighted_loss(gs).backward()
    return out, gs, meta, [t.grad for t in ours], [t.grad for t in ref]


def _depth_err(a, b):
    a, b = a.detach(), b.detach()
    return float(((a - b).abs() / b.abs().clamp_min(1.0)).max())


@pytest.mark.parametrize("case", ["rgb", "sh2_two_cameras", "faint"])
def test_images_and_gradients_match_gsplat_float64(case):
    pose = random_pose(11)
    kw = {"background": torch.tensor([0.1, 0.5, 0.8], dtype=torch.float64)}
    poses = pose
    if case == "sh2_two_cameras":
        poses = np.stack([pose, random_pose(12)])
        params = random_gaussians(300, 11, pose, dtype=torch.float64, sh_degree=2)
        kw["background"] = torch.tensor([[0.1, 0.5, 0.8], [0.9, 0.2, 0.0]], dtype=torch.float64)
    elif case == "faint":            # opacities around the 1/255 cut-off, so the skip rule matters
        params = random_gaussians(300, 13, pose, dtype=torch.float64)
        params["opacity_logits"] = torch.empty(300, dtype=torch.float64).uniform_(-6.5, -3.0)
    else:
        params = random_gaussians(300, 11, pose, dtype=torch.float64)
    # unnormalised quaternions and anisotropic scales exercise normalisation and covariance
    params["quats"] = params["quats"] * torch.linspace(0.2, 5.0, 300, dtype=torch.float64)[:, None]
    out, gs, meta, g_ours, g_ref = _both(params, poses, pinhole(W, H), **kw)
    assert out.alpha.max() > (0.05 if case == "faint" else 0.9)
    assert (out.rgb - gs.rgb).abs().max() < 1e-10
    assert (out.alpha - gs.alpha).abs().max() < 1e-10
    assert _depth_err(out.depth, gs.depth) < 1e-10
    visible = out.meta["visible"]
    assert torch.equal(visible, visible & (meta["radii"] > 0).all(-1)), "gsplat culls a Gaussian we render"
    for key in ("means2d", "conics", "depths"):
        assert (out.meta[key][visible] - meta[key][visible]).abs().max() < 1e-9, key
    for name, a, b in zip(PARAMS, g_ours, g_ref):
        assert max_rel(a, b) < 1e-9, name


def test_images_and_gradients_match_gsplat_float32():
    pose = random_pose(21)
    params = random_gaussians(400, 21, pose)
    out, gs, _meta, g_ours, g_ref = _both(params, pose, pinhole(W, H),
                                           background=torch.tensor([0.3, 0.3, 0.3]))
    assert (out.rgb - gs.rgb).abs().max() < 1e-5
    assert (out.alpha - gs.alpha).abs().max() < 1e-5
    assert _depth_err(out.depth, gs.depth) < 1e-5
    for name, a, b in zip(PARAMS, g_ours, g_ref):
        assert max_rel(a, b) < 1e-4, name


@pytest.mark.parametrize("mutation", ["quats_xyzw", "scales_not_exp", "dilation_0.1", "no_background"])
def test_a_wrong_convention_would_be_caught(mutation):
    pose = random_pose(31)
    params = random_gaussians(200, 31, pose, dtype=torch.float64)
    bg = torch.tensor([0.2, 0.4, 0.6], dtype=torch.float64)
    K = pinhole(W, H)
    out = rasterize(*leaves(params, False), pose, K, W, H, near=NEAR, background=bg)
    ref = leaves(params, False)
    kw = {"background": bg}
    if mutation == "quats_xyzw":
        ref[1] = ref[1][:, [1, 2, 3, 0]]
    elif mutation == "scales_not_exp":              # log-scales taken for scales: exp(log(exp(x)))
        ref[2] = torch.exp(ref[2])
    elif mutation == "dilation_0.1":
        kw["eps2d"] = 0.1
    else:
        kw["background"] = None
    rgb, _alpha, _depth, _meta = rasterize_gsplat_torch(*ref, pose, K, W, H, near=NEAR, **kw)
    assert (out.rgb - rgb).abs().max() > 1e-3
