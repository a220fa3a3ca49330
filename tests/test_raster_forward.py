"""Forward pass of nuav2.splat.rasterize against the dense plain-torch reference."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from raster_scenes import PARAMS, leaves, pinhole, random_gaussians, random_pose

from nuav2.splat import rasterize
from nuav2.splat.dense_reference import rasterize_dense

W, H = 70, 50          # 5 x 4 tiles, the last column and row partial


def _assert_images_close(out, ref, atol=1e-5):
    for image in out[:3]:
        assert torch.isfinite(image).all()
    assert (out.rgb - ref.rgb).abs().max() <= atol
    assert (out.alpha - ref.alpha).abs().max() <= atol
    # expected depth is in metres (up to ~10 here): compare relative to max(1, depth)
    assert ((out.depth - ref.depth).abs() / ref.depth.abs().clamp_min(1.0)).max() <= atol


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_forward_matches_dense_reference_float32(seed):
    pose = random_pose(seed)
    params = random_gaussians(400, seed, pose)
    K = pinhole(W, H)
    bg = torch.tensor([0.2, 0.5, 0.9])
    out = rasterize(*leaves(params, False), pose, K, W, H, near=0.2, background=bg)
    ref = rasterize_dense(*leaves(params, False), pose, K, W, H, near=0.2, background=bg)
    assert out.rgb.shape == (H, W, 3) and out.alpha.shape == (H, W) and out.depth.shape == (H, W)
    _assert_images_close(out, ref)
    assert out.alpha.max() > 0.9, "the scene should cover pixels opaquely"
    assert torch.equal(out.meta["visible"], ref.meta["visible"])
    assert torch.equal(out.meta["radii"], ref.meta["radii"])


def test_forward_matches_dense_reference_float64():
    pose = random_pose(7)
    params = random_gaussians(200, 7, pose, dtype=torch.float64)
    K = pinhole(W, H)
    out = rasterize(*leaves(params, False), pose, K, W, H)
    ref = rasterize_dense(*leaves(params, False), pose, K, W, H)
    assert out.rgb.dtype == torch.float64
    _assert_images_close(out, ref, atol=1e-12)


def test_sh_colours_match_reference():
    pose = random_pose(3)
    params = random_gaussians(300, 3, pose, sh_degree=2)
    K = pinhole(W, H)
    for degree in (0, 2):
        out = rasterize(*leaves(params, False), pose, K, W, H, sh_degree=degree)
        ref = rasterize_dense(*leaves(params, False), pose, K, W, H, sh_degree=degree)
        _assert_images_close(out, ref)
    constant = rasterize(*leaves(params, False), pose, K, W, H, sh_degree=0).rgb
    assert (out.rgb - constant).abs().max() > 1e-3, "degree 2 must add view dependence"


def test_batch_of_cameras_equals_single_calls():
    poses = np.stack([random_pose(s) for s in (10, 11, 12)])
    params = random_gaussians(300, 10, poses[0])
    K = pinhole(W, H)
    batch = rasterize(*leaves(params, False), poses, K, W, H)
    assert batch.rgb.shape == (3, H, W, 3) and batch.meta["means2d"].shape == (3, 300, 2)
    for c in range(3):
        single = rasterize(*leaves(params, False), poses[c], K, W, H)
        assert torch.equal(batch.rgb[c], single.rgb)
        assert torch.equal(batch.depth[c], single.depth)
        assert torch.equal(batch.meta["radii"][c], single.meta["radii"][0])


def test_background_fills_the_transparent_part():
    pose = random_pose(4)
    params = random_gaussians(150, 4, pose)
    K = pinhole(W, H)
    black = rasterize(*leaves(params, False), pose, K, W, H)
    white = rasterize(*leaves(params, False), pose, K, W, H, background=torch.ones(3))
    assert torch.allclose(white.rgb - black.rgb, (1 - black.alpha)[..., None].expand(-1, -1, 3), atol=1e-6)
    assert (black.alpha < 0.5).any(), "some pixels must stay see-through for this check to mean something"


def test_depth_is_expected_camera_z():
    """One opaque splat at depth 5 seen head-on: expected depth 5 wherever it is visible."""
    params = {"means": torch.tensor([[0.0, 0.0, 5.0]]), "quats": torch.tensor([[1.0, 0, 0, 0]]),
              "log_scales": torch.full((1, 3), np.log(0.5)), "opacity_logits": torch.tensor([3.0]),
              "colors": torch.tensor([[1.0, 0.5, 0.25]])}
    out = rasterize(*leaves(params, False), np.eye(4), pinhole(W, H), W, H)
    seen = out.alpha > 0
    assert seen.sum() > 100
    assert torch.allclose(out.depth[seen], torch.tensor(5.0), atol=1e-5)
    assert (out.depth[~seen] == 0).all()
    centre = out.rgb[H // 2, W // 2]
    assert torch.allclose(centre / centre[0], torch.tensor([1.0, 0.5, 0.25]), atol=1e-5)


@pytest.mark.parametrize("bad, message", [
    ({"means": torch.zeros(5, 2)}, "means"),
    ({"quats": torch.zeros(5, 3)}, "quats"),
    ({"log_scales": torch.zeros(5, 3, dtype=torch.float64)}, "dtype"),
    ({"opacity_logits": torch.zeros(4)}, "opacity_logits"),
    ({"colors": torch.zeros(5, 5, 3)}, "SH"),
])
def test_bad_gaussian_inputs_are_named(bad, message):
    params = random_gaussians(5, 0)
    params.update(bad)
    with pytest.raises(ValueError, match=message):
        rasterize(*[params[k] for k in PARAMS], np.eye(4), pinhole(W, H), W, H)


def test_bad_camera_inputs_are_named():
    params = [random_gaussians(5, 0)[k] for k in PARAMS]
    skew = np.eye(4)
    skew[0, 1] = 0.5
    with pytest.raises(ValueError, match="rigid"):
        rasterize(*params, skew, pinhole(W, H), W, H)
    with pytest.raises(ValueError, match="K must"):
        rasterize(*params, np.eye(4), np.eye(2), W, H)
    with pytest.raises(ValueError, match="near"):
        rasterize(*params, np.eye(4), pinhole(W, H), W, H, near=2.0, far=1.0)
    with pytest.raises(ValueError, match="width/height"):
        rasterize(*params, np.eye(4), pinhole(W, H), 0, H)
    with pytest.raises(ValueError, match="backend"):
        rasterize(*params, np.eye(4), pinhole(W, H), W, H, backend="opengl")


@pytest.mark.skipif(torch.cuda.is_available(), reason="checks the refusal on a machine without CUDA")
def test_gsplat_backend_refuses_clearly_without_cuda():
    params = [random_gaussians(5, 0)[k] for k in PARAMS]
    with pytest.raises(RuntimeError, match="gsplat"):
        rasterize(*params, np.eye(4), pinhole(W, H), W, H, backend="gsplat")
    assert rasterize(*params, np.eye(4), pinhole(W, H), W, H, backend="auto").meta["backend"] == "cpu"
