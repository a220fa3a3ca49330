"""A seeded random scene with near, big splats: the rasterizer benchmark's occlusion-heavy workload.

Gaussians fill the view frustum (10 % wider than the image, so splats beside it reach in) at
camera depths log-uniform in 2-80 m, with world sizes of 0.22-1 m, random orientations,
opacities from a wide logit distribution (many faint, many near-opaque) and random colours.
The nearest splats cover hundreds of pixels each, so most tile-Gaussian pairs lie behind
pixels that have already stopped: the case where binning, not compositing, decides the time.
Deterministic per seed.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from nuav2.bench.street_scene import StreetScene, forward_camera

DEPTH_M = (2.0, 80.0)
LOG_SCALE = (-1.5, 0.0)
OPACITY_LOGIT = (0.5, 2.0)      # mean, std
FRUSTUM_MARGIN = 1.1


def make_near_splat_scene(n: int, width: int, height: int, seed: int = 0) -> StreetScene:
    """n Gaussians in front of the benchmark's forward camera (same intrinsics as the street)."""
    rng = np.random.default_rng(seed)
    world_T_cam, K = forward_camera(width, height)
    z = np.exp(rng.uniform(math.log(DEPTH_M[0]), math.log(DEPTH_M[1]), n))
    half_x = FRUSTUM_MARGIN * 0.5 * width / K[0, 0]
    half_y = FRUSTUM_MARGIN * 0.5 * height / K[1, 1]
    cam_points = np.column_stack([rng.uniform(-half_x, half_x, n) * z, rng.uniform(-half_y, half_y, n) * z,
                                  z])
    means = cam_points @ world_T_cam[:3, :3].T + world_T_cam[:3, 3]
    quats = rng.normal(size=(n, 4))
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    f32 = torch.float32
    return StreetScene(
        torch.tensor(means, dtype=f32), torch.tensor(quats, dtype=f32),
        torch.tensor(rng.uniform(*LOG_SCALE, (n, 3)), dtype=f32),
        torch.tensor(rng.normal(*OPACITY_LOGIT, n), dtype=f32),
        torch.tensor(rng.uniform(0.0, 1.0, (n, 3)), dtype=f32), world_T_cam, K, width, height)
