"""Numerical hard cases: every one renders finite images and finite gradients, and agrees with
the dense reference (or with an equivalent well-conditioned scene)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from raster_scenes import PARAMS, grads_of, leaves, pinhole, random_gaussians

from nuav2.splat import rasterize
from nuav2.splat.dense_reference import rasterize_dense

W, H = 40, 30
K = pinhole(W, H, f=30.0)
NEAR = 0.25


def _scene(n: int, seed: int, **kw) -> dict[str, torch.Tensor]:
    return random_gaussians(n, seed, depth=(1.0, 6.0), half_fov=0.6, **kw)


def _with(base: dict, idx, **values) -> dict:
    out = {k: v.clone() for k, v in base.items()}
    for key, val in values.items():
        out[key][idx] = torch.as_tensor(val, dtype=out[key].dtype)
    return out


def _case_tiny_scales():
    return _with(_scene(60, 1), slice(0, 20), log_scales=torch.tensor([-30.0, -50.0, -12.0]))


def _case_huge_scales():
    return _with(_scene(60, 2), slice(0, 3), log_scales=torch.tensor([[8.0, 8.0, 8.0], [40.0, 2.0, 2.0],
                                                                       [5.0, -3.0, 60.0]]))


def _case_anisotropy_1000():
    p = _scene(60, 3)
    p["log_scales"][:30] = torch.log(torch.tensor([1.0, 1e-3, 0.3]))
    return p


def _case_near_plane():
    p = _scene(40, 4)
    z = torch.tensor([NEAR, NEAR + 1e-4, NEAR - 1e-4, NEAR + 0.02, 0.0, -1e-3])
    p["means"][: len(z)] = torch.column_stack([torch.zeros_like(z), torch.zeros_like(z), z])
    p["log_scales"][: len(z)] = math.log(0.4)        # straddles the plane: extends behind the camera
    return p


def _case_behind_camera():
    p = _scene(40, 5)
    p["means"][:30, 2] *= -1.0
    return p


def _case_image_edges():
    p = _scene(40, 6)
    u = torch.tensor([0.0, W, -3.0, W + 3.0, -2000.0, W / 2, W / 2, 1e5])
    v = torch.tensor([H / 2, H / 2, 0.0, H, H / 2, -1e3, H + 1e3, H / 2])
    z = torch.full_like(u, 3.0)
    p["means"][: len(u)] = torch.column_stack([(u - W / 2) * z / 30.0, (v - H / 2) * z / 30.0, z])
    p["log_scales"][4:8] = 4.0                        # far outside but wide: may still reach the image
    return p


def _case_opacity_saturated():
    return _with(_scene(60, 7), slice(0, 30), opacity_logits=torch.tensor([20.0, 60.0, 1e4] * 10))


def _case_many_equal_depths():
    p = _scene(60, 8)
    p["means"][:, 2] = 3.0
    return p


def _case_all_faint():
    return _with(_scene(30, 9), slice(None), opacity_logits=-8.0)


CASES = {"tiny_scales": _case_tiny_scales, "huge_scales": _case_huge_scales,
         "anisotropy_1000": _case_anisotropy_1000, "near_plane": _case_near_plane,
         "behind_camera": _case_behind_camera, "image_edges": _case_image_edges,
         "opacity_saturated": _case_opacity_saturated, "equal_depths": _case_many_equal_depths,
         "all_faint": _case_all_faint}


@pytest.mark.parametrize("name", sorted(CASES))
def test_hard_case_is_finite_and_matches_reference(name):
    params = CASES[name]()
    out, g_kernel = grads_of(rasterize, params, np.eye(4), K, W, H, near=NEAR)
    ref, g_dense = grads_of(rasterize_dense, params, np.eye(4), K, W, H, near=NEAR)
    for image, ref_image in zip(out[:3], ref[:3]):
        assert torch.isfinite(image).all(), name
        assert ((image - ref_image).abs() / ref_image.abs().clamp_min(1.0)).max() <= 1e-5, name
    for param, a, b in zip(PARAMS, g_kernel, g_dense):
        assert torch.isfinite(a).all(), f"{name}: non-finite {param} gradient"
        tol = 1e-3 * float(b.abs().max()) + 1e-6
        assert float((a - b).abs().max()) <= tol, f"{name}: {param} gradient off by {(a - b).abs().max():.3g}"


def test_opacity_one_still_clamped_at_0999():
    """Opacity sigmoid(100) = 1: the pixel under the centre gets alpha 0.999, never 1."""
    z = 3.0
    centre_px = (0.5 * z / 30.0, 0.5 * z / 30.0)          # lands exactly on pixel centre (20.5, 15.5)
    params = {"means": torch.tensor([[centre_px[0], centre_px[1], z]]),
              "quats": torch.tensor([[1.0, 0, 0, 0]]), "log_scales": torch.zeros(1, 3),
              "opacity_logits": torch.tensor([100.0]), "colors": torch.ones(1, 3)}
    out, grads = grads_of(rasterize, params, np.eye(4), K, W, H)
    alpha = out.alpha.detach()
    assert abs(float(alpha[H // 2, W // 2]) - 0.999) < 1e-6
    assert float(alpha.max()) <= 0.999 + 1e-7
    assert all(torch.isfinite(g).all() for g in grads)


def test_single_gaussian_covering_the_whole_image():
    params = {"means": torch.tensor([[0.0, 0.0, 4.0]]), "quats": torch.tensor([[1.0, 0, 0, 0]]),
              "log_scales": torch.full((1, 3), math.log(40.0)), "opacity_logits": torch.tensor([2.0]),
              "colors": torch.tensor([[0.2, 0.4, 0.6]])}
    out, grads = grads_of(rasterize, params, np.eye(4), K, W, H)
    o = float(torch.sigmoid(torch.tensor(2.0)))
    alpha = out.alpha.detach()
    assert float(alpha.min()) > 0.99 * o and float(alpha.max()) <= o + 1e-6, "flat over the image"
    assert torch.allclose(out.depth, torch.tensor(4.0), atol=1e-4)
    assert out.meta["radii"].min() > max(W, H)
    assert all(torch.isfinite(g).all() for g in grads)


def test_empty_scene():
    params = {k: v[:0] for k, v in _scene(5, 0).items()}
    out, grads = grads_of(rasterize, params, np.eye(4), K, W, H, background=torch.tensor([0.1, 0.2, 0.3]))
    assert torch.equal(out.rgb, torch.tensor([0.1, 0.2, 0.3]).expand(H, W, 3))
    assert (out.alpha == 0).all() and (out.depth == 0).all()
    assert [tuple(g.shape) for g in grads] == [(0, 3), (0, 4), (0, 3), (0,), (0, 3)]


def test_zero_and_unnormalised_quaternions():
    base = _scene(50, 11)
    unit = base["quats"] / base["quats"].norm(dim=-1, keepdim=True)
    identity = torch.tensor([1.0, 0.0, 0.0, 0.0]).expand(50, 4)
    ref_unit = rasterize(*leaves({**base, "quats": unit}, False), np.eye(4), K, W, H)
    ref_identity = rasterize(*leaves({**base, "quats": identity.clone()}, False), np.eye(4), K, W, H)
    for scale in (1e-6, 1e5):
        out = rasterize(*leaves({**base, "quats": unit * scale}, False), np.eye(4), K, W, H)
        assert (out.rgb - ref_unit.rgb).abs().max() < 1e-5
    zero = {**base, "quats": torch.zeros(50, 4)}
    out, grads = grads_of(rasterize, zero, np.eye(4), K, W, H)
    assert (out.rgb - ref_identity.rgb).abs().max() < 1e-6, "a zero quaternion is the identity rotation"
    assert all(torch.isfinite(g).all() for g in grads)


def test_city_scale_coordinates_match_a_local_frame():
    """Gaussians and camera 10 km from the origin render like the same scene at the origin."""
    local = _scene(80, 12)
    local["means"] = torch.round(local["means"] * 128) / 128      # exactly representable at 1e4 in float32
    offset = torch.tensor([1.0e4, -1.0e4, 1.0e4])
    far = {**local, "means": local["means"] + offset}
    assert torch.equal(far["means"] - offset, local["means"])
    pose_far = np.eye(4)
    pose_far[:3, 3] = offset.double().numpy()
    out_far, g_far = grads_of(rasterize, far, pose_far, K, W, H)
    out_local, g_local = grads_of(rasterize, local, np.eye(4), K, W, H)
    for a, b in zip(out_far[:3], out_local[:3]):
        assert torch.isfinite(a).all()
        assert (a - b).abs().max() <= 1e-5
    for a, b in zip(g_far, g_local):
        assert torch.isfinite(a).all()
        assert (a - b).abs().max() <= 1e-4 * b.abs().max() + 1e-6


def test_non_finite_parameters_cull_the_gaussian():
    base = _scene(30, 13)
    bad = {k: v.clone() for k, v in base.items()}
    bad["means"][0, 0] = float("nan")
    bad["means"][1, 2] = float("inf")
    bad["log_scales"][2] = float("nan")
    bad["quats"][3] = float("nan")
    bad["opacity_logits"][4] = float("nan")
    out, grads = grads_of(rasterize, bad, np.eye(4), K, W, H)
    assert not out.meta["visible"][0, :5].any()
    for image in out[:3]:
        assert torch.isfinite(image).all()
    for g in grads:
        assert torch.isfinite(g[5:]).all()
    kept = {k: v[5:] for k, v in base.items()}
    assert (rasterize(*leaves(kept, False), np.eye(4), K, W, H).rgb - out.rgb).abs().max() < 1e-6


@pytest.mark.parametrize("sh_degree", [None, 1])
@pytest.mark.parametrize("value", [float("nan"), float("inf"), -float("inf")])
def test_non_finite_colour_culls_the_gaussian(value, sh_degree):
    """A NaN/inf colour (or SH coefficient) culls that Gaussian: images and every gradient stay
    finite and equal those of the scene without it (issue 10, finding 17)."""
    base = _scene(40, 14, sh_degree=sh_degree)
    bad = {k: v.clone() for k, v in base.items()}
    bad["colors"][[3, 17]] = value if sh_degree is None else bad["colors"][[3, 17]]
    if sh_degree is not None:
        bad["colors"][3, 2, 1] = value
        bad["colors"][17, 0, 0] = value
    kept_ids = [i for i in range(40) if i not in (3, 17)]
    kept = {k: v[kept_ids] for k, v in base.items()}
    for fn in (rasterize, rasterize_dense):
        out, grads = grads_of(fn, bad, np.eye(4), K, W, H, near=NEAR)
        ref, ref_grads = grads_of(fn, kept, np.eye(4), K, W, H, near=NEAR)
        assert not out.meta["visible"][0, [3, 17]].any()
        for image, ref_image in zip(out[:3], ref[:3]):
            assert torch.isfinite(image).all()
            assert (image - ref_image).abs().max() < 1e-6
        for name, g, g_ref in zip(PARAMS, grads, ref_grads):
            assert torch.isfinite(g).all(), name
            assert (g[[3, 17]] == 0).all(), name
            assert (g[kept_ids] - g_ref).abs().max() <= 1e-5 * g_ref.abs().max() + 1e-7, name


@pytest.mark.parametrize("value", [float("nan"), float("inf")])
def test_non_finite_background_is_an_error_naming_it(value):
    params = _scene(10, 15)
    for fn in (rasterize, rasterize_dense):
        with pytest.raises(ValueError, match="background must be finite"):
            fn(*leaves(params, False), np.eye(4), K, W, H, background=torch.tensor([0.1, value, 0.2]))
