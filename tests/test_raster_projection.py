"""Projection oracles and round trips: pinhole centres, EWA covariances from an independent numpy
formula, the FoV clamp, camera inversion, and invariance under a rigid motion of the world."""

from __future__ import annotations

import math

import numpy as np
import torch
from raster_scenes import PARAMS, grads_of, leaves, pinhole, random_gaussians, random_pose

from nuav2.geometry import T_inverse, quat_multiply, quat_normalize, quat_to_rot
from nuav2.splat import rasterize
from nuav2.splat._inputs import prepare_cameras
from nuav2.splat.constants import ALPHA_MIN, EPS2D, FOV_CLAMP

W, H = 64, 48


def _ewa_oracle(params, world_T_cam, K, width, height):
    """means2d, depth and conic of every Gaussian, in float64 numpy, straight from the EWA formulas."""
    cam_T_world = T_inverse(world_T_cam)
    m = params["means"].double().numpy()
    p = m @ cam_T_world[:3, :3].T + cam_T_world[:3, 3]
    R = quat_to_rot(params["quats"].double().numpy())
    S = np.exp(params["log_scales"].double().numpy())
    cov_world = R @ (S[:, :, None] ** 2 * np.swapaxes(R, 1, 2))
    cov_cam = cam_T_world[:3, :3] @ cov_world @ cam_T_world[:3, :3].T
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    x, y, z = p.T
    lim_x = (cx / fx + FOV_CLAMP * 0.5 * width / fx, (width - cx) / fx + FOV_CLAMP * 0.5 * width / fx)
    lim_y = (cy / fy + FOV_CLAMP * 0.5 * height / fy, (height - cy) / fy + FOV_CLAMP * 0.5 * height / fy)
    tx = z * np.clip(x / z, -lim_x[0], lim_x[1])
    ty = z * np.clip(y / z, -lim_y[0], lim_y[1])
    J = np.zeros((len(z), 2, 3))
    J[:, 0, 0], J[:, 0, 2] = fx / z, -fx * tx / z**2
    J[:, 1, 1], J[:, 1, 2] = fy / z, -fy * ty / z**2
    cov2d = J @ cov_cam @ np.swapaxes(J, 1, 2) + EPS2D * np.eye(2)
    conic = np.linalg.inv(cov2d)
    uv = np.column_stack([fx * x / z + cx, fy * y / z + cy])
    return uv, z, np.stack([conic[:, 0, 0], conic[:, 0, 1], conic[:, 1, 1]], -1), cov2d


def test_projection_matches_numpy_ewa_oracle():
    pose = random_pose(1)
    params = random_gaussians(200, 1, pose, dtype=torch.float64, half_fov=1.2)   # some beyond the FoV clamp
    K = pinhole(W, H)
    out = rasterize(*leaves(params, False), pose, K, W, H)
    uv, z, conic, _ = _ewa_oracle(params, pose, K, W, H)
    vis = out.meta["visible"][0].numpy()
    assert 50 < vis.sum() < 200, "the scene should have visible and culled Gaussians"
    np.testing.assert_allclose(out.meta["means2d"][0].detach().numpy()[vis], uv[vis], rtol=0, atol=1e-9)
    np.testing.assert_allclose(out.meta["depths"][0].detach().numpy()[vis], z[vis], rtol=1e-12)
    np.testing.assert_allclose(out.meta["conics"][0].detach().numpy()[vis], conic[vis], rtol=1e-8, atol=1e-12)


def test_isotropic_gaussian_on_axis_radius_oracle():
    sigma, z, f, o = 0.2, 4.0, 50.0, 0.6
    params = {"means": torch.tensor([[0.0, 0.0, z]]), "quats": torch.tensor([[0.3, -0.5, 0.1, 0.8]]),
              "log_scales": torch.full((1, 3), math.log(sigma)),
              "opacity_logits": torch.tensor([math.log(o / (1 - o))]), "colors": torch.ones(1, 3)}
    out = rasterize(*leaves(params, False), np.eye(4), pinhole(W, H, f), W, H)
    var = (f * sigma / z) ** 2 + EPS2D
    conic = out.meta["conics"][0, 0].detach()
    assert torch.allclose(conic, torch.tensor([1 / var, 0.0, 1 / var]), rtol=1e-6, atol=1e-9)
    expected_radius = math.ceil(math.sqrt(2 * math.log(o / ALPHA_MIN)) * math.sqrt(var))
    assert out.meta["radii"][0, 0].tolist() == [expected_radius, expected_radius]


def test_near_and_far_planes_cull():
    z = torch.tensor([0.5, 0.99, 1.0, 5.0, 10.0, 10.01])
    params = {"means": torch.column_stack([torch.zeros(6), torch.zeros(6), z]),
              "quats": torch.eye(4)[[0] * 6], "log_scales": torch.full((6, 3), -2.0),
              "opacity_logits": torch.zeros(6), "colors": torch.ones(6, 3)}
    out = rasterize(*leaves(params, False), np.eye(4), pinhole(W, H), W, H, near=1.0, far=10.0)
    assert out.meta["visible"][0].tolist() == [False, False, True, True, True, False]


def test_camera_inversion_round_trip():
    poses = np.stack([random_pose(s) for s in range(4)])
    cams = prepare_cameras(poses, pinhole(W, H))
    np.testing.assert_allclose(cams.cam_T_world @ poses, np.broadcast_to(np.eye(4), (4, 4, 4)), atol=1e-12)
    np.testing.assert_allclose(cams.centres_world, poses[:, :3, 3])
    assert cams.batched and not prepare_cameras(poses[0], pinhole(W, H)).batched


def test_rigid_motion_of_world_and_camera_changes_nothing():
    """Move Gaussians and camera by the same rigid T: same image; mean gradients rotate with T."""
    pose = random_pose(2)
    params = random_gaussians(300, 2, pose, dtype=torch.float64)
    K = pinhole(W, H)
    rng = np.random.default_rng(5)
    q_T = quat_normalize(rng.normal(size=4))
    R_T = quat_to_rot(q_T)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R_T, rng.normal(0, 10, 3)
    moved = dict(params)
    moved["means"] = torch.tensor(params["means"].numpy() @ R_T.T + T[:3, 3])
    moved["quats"] = torch.tensor(quat_multiply(q_T, params["quats"].numpy()))
    out_a, g_a = grads_of(rasterize, params, pose, K, W, H)
    out_b, g_b = grads_of(rasterize, moved, T @ pose, K, W, H)
    for a, b in zip(out_a[:3], out_b[:3]):
        assert (a - b).abs().max() < 1e-9
    assert torch.equal(out_a.meta["radii"], out_b.meta["radii"])
    np.testing.assert_allclose(g_b[0].numpy(), g_a[0].numpy() @ R_T.T, atol=1e-7 * float(g_a[0].abs().max()))
    for name, a, b in zip(PARAMS[2:], g_a[2:], g_b[2:]):
        assert (a - b).abs().max() <= 1e-7 * float(a.abs().max()), name


def test_quaternion_sign_does_not_matter():
    pose = random_pose(3)
    params = random_gaussians(200, 3, pose)
    flipped = {**params, "quats": -params["quats"]}
    a = rasterize(*leaves(params, False), pose, pinhole(W, H), W, H)
    b = rasterize(*leaves(flipped, False), pose, pinhole(W, H), W, H)
    assert torch.equal(a.rgb, b.rgb)
