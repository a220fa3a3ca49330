"""A synthetic street of Gaussians seen by a forward camera: the rasterizer benchmark's workload.

Ground (road, lane marks, sidewalks), two rows of facades, parked and driving cars and a few
trees, with surface-aligned flat Gaussians sized from the point density, and opacities drawn
like a trained model's (most near-opaque, a tail of faint ones). Deterministic per seed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

CAMERA_HEIGHT_M = 1.6
HFOV_DEG = 70.0
CORRIDOR_M = (-5.0, 90.0)        # along the road (world x), camera at x = 0
HALF_WIDTH_M = 14.0              # facades at y = +-HALF_WIDTH_M


@dataclass(frozen=True)
class StreetScene:
    """Gaussian parameters in the trainer's raw form plus one forward camera."""

    means: torch.Tensor
    quats: torch.Tensor
    log_scales: torch.Tensor
    opacity_logits: torch.Tensor
    colors: torch.Tensor
    world_T_cam: np.ndarray
    K: np.ndarray
    width: int
    height: int

    def tensors(self, requires_grad: bool = False) -> list[torch.Tensor]:
        ts = [self.means, self.quats, self.log_scales, self.opacity_logits, self.colors]
        return [t.detach().clone().requires_grad_(requires_grad) for t in ts]


def forward_camera(width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV camera at the origin, CAMERA_HEIGHT_M up, looking along world +x (z up)."""
    world_T_cam = np.eye(4)
    world_T_cam[:3, :3] = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    world_T_cam[:3, 3] = [0.0, 0.0, CAMERA_HEIGHT_M]
    f = 0.5 * width / math.tan(math.radians(HFOV_DEG) / 2)
    K = np.array([[f, 0.0, width / 2], [0.0, f, height / 2], [0.0, 0.0, 1.0]])
    return world_T_cam, K


def _quat_from_normal_jitter(normal_axis: int, n: int, rng: np.random.Generator, jitter: float) -> np.ndarray:
    """Quaternions rotating the Gaussian's thin z axis onto a world axis, with small random tilt."""
    base = {2: (1.0, 0.0, 0.0, 0.0),                               # z stays z (ground)
            1: (math.sqrt(0.5), math.sqrt(0.5), 0.0, 0.0),         # z -> -y (facade)
            0: (math.sqrt(0.5), 0.0, math.sqrt(0.5), 0.0)}[normal_axis]  # z -> x (car front)
    q = np.tile(np.asarray(base), (n, 1)) + rng.normal(0.0, jitter, (n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _surface(n: int, rng, lo, hi, normal_axis: int, colour_fn, thin: float = 0.08):
    """n Gaussians uniformly on an axis-aligned rectangle (lo, hi give the 3D box)."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    pts = rng.uniform(lo, hi, (n, 3))
    extent = np.delete(hi - lo, normal_axis)
    spacing = math.sqrt(max(extent[0] * extent[1], 1e-6) / max(n, 1))
    scales = np.empty((n, 3))
    scales[:, :2] = spacing * 0.8 * np.exp(rng.normal(0.0, 0.3, (n, 2)))
    scales[:, 2] = spacing * thin * np.exp(rng.normal(0.0, 0.3, n))
    return pts, _quat_from_normal_jitter(normal_axis, n, rng, 0.05), scales, colour_fn(pts, rng)


def _ground_colour(pts, rng):
    y = pts[:, 1]
    c = np.where(np.abs(y)[:, None] < 7.0, [0.32, 0.32, 0.34], [0.55, 0.52, 0.48])
    dash = (np.abs(np.abs(y) - 3.5) < 0.08) & (np.mod(pts[:, 0], 6.0) < 3.0)
    centre = np.abs(y) < 0.1
    c = np.where((dash | centre)[:, None], [0.9, 0.9, 0.85], c)
    return c + rng.normal(0.0, 0.03, c.shape)


def _facade_colour(pts, rng):
    block = np.floor(pts[:, 0] / 12.0).astype(int)
    palette = np.array([[0.6, 0.45, 0.35], [0.7, 0.7, 0.65], [0.45, 0.5, 0.6], [0.8, 0.75, 0.6]])
    c = palette[block % len(palette)]
    window = (np.mod(pts[:, 2], 3.0) > 1.2) & (np.mod(pts[:, 0], 3.0) > 1.0)
    c = np.where(window[:, None], [0.15, 0.2, 0.25], c)
    return c + rng.normal(0.0, 0.04, c.shape)


def make_street_scene(n: int, width: int, height: int, seed: int = 0) -> StreetScene:
    """n Gaussians: 45% ground, 35% facades, 12% cars, 8% trees; camera at the corridor start."""
    rng = np.random.default_rng(seed)
    x0, x1 = CORRIDOR_M
    parts = []
    n_ground = int(0.45 * n)
    parts.append(_surface(n_ground, rng, (x0, -HALF_WIDTH_M, 0.0), (x1, HALF_WIDTH_M, 0.02), 2,
                          _ground_colour))
    n_fac = int(0.35 * n)
    for side in (-1.0, 1.0):
        k = n_fac // 2
        lo = (x0, side * HALF_WIDTH_M - 0.05, 0.0)
        hi = (x1, side * HALF_WIDTH_M + 0.05, 14.0)
        parts.append(_surface(k, rng, lo, hi, 1, _facade_colour))
    n_cars = int(0.12 * n)
    n_car_boxes = 14
    car_rng = np.random.default_rng(seed + 1)
    for _ in range(n_car_boxes):
        k = n_cars // n_car_boxes
        cx = car_rng.uniform(6.0, 70.0)
        cy = car_rng.choice([-9.5, -5.2, -1.8, 1.8, 5.2, 9.5])
        lo = (cx - 2.3, cy - 0.9, 0.2)
        hi = (cx + 2.3, cy + 0.9, 1.6)
        colour = car_rng.uniform(0.05, 0.9, 3)
        pts = rng.uniform(lo, hi, (k, 3))
        spacing = (4.6 * 1.8 * 1.4 / max(k, 1)) ** (1 / 3)
        scales = spacing * 0.7 * np.exp(rng.normal(0.0, 0.3, (k, 3)))
        q = rng.normal(0.0, 1.0, (k, 4))
        parts.append((pts, q / np.linalg.norm(q, axis=1, keepdims=True), scales,
                      np.tile(colour, (k, 1)) + rng.normal(0.0, 0.03, (k, 3))))
    n_rest = n - sum(len(p[0]) for p in parts)
    trees = rng.uniform((x0, -HALF_WIDTH_M + 1.0, 3.0), (x1, HALF_WIDTH_M - 1.0, 7.0), (max(n_rest, 0), 3))
    trees[:, 1] = np.sign(trees[:, 1]) * rng.uniform(9.0, 12.5, len(trees))
    tq = rng.normal(0.0, 1.0, (len(trees), 4))
    parts.append((trees, tq / np.linalg.norm(tq, axis=1, keepdims=True),
                  0.25 * np.exp(rng.normal(0.0, 0.4, (len(trees), 3))),
                  np.tile([0.2, 0.45, 0.15], (len(trees), 1)) + rng.normal(0.0, 0.05, (len(trees), 3))))
    means, quats, scales, colours = (np.concatenate(c) for c in zip(*parts))
    opaque = rng.random(len(means)) < 0.75
    logits = np.where(opaque, rng.normal(2.5, 1.0, len(means)), rng.normal(-1.5, 1.0, len(means)))
    world_T_cam, K = forward_camera(width, height)
    f32 = torch.float32
    return StreetScene(
        torch.tensor(means, dtype=f32), torch.tensor(quats, dtype=f32),
        torch.tensor(np.log(scales), dtype=f32), torch.tensor(logits, dtype=f32),
        torch.tensor(np.clip(colours, 0.0, 1.0), dtype=f32), world_T_cam, K, width, height)
