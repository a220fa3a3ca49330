"""The sky of a reconstruction: a lat-long texture looked up by view direction, and pixel rays.

Directions are in the scene frame, a pure translation of the city frame, so the sky never turns
with the camera. Pixel rays are computed once per camera model in float64 on the CPU and cached
per device, so every device looks the sky up along the same rays.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
import torch
import torch.nn.functional as F

from nuav2.geometry import F64
from nuav2.rig import CameraSpec

SKY_ELEV_MIN = -math.radians(20.0)  # the sky texture spans this elevation up to the zenith
SKY_INIT_RGB = (0.7, 0.8, 0.9)  # a new sky's colour everywhere, before the views are seen


def inverse_sigmoid(p: torch.Tensor | float) -> torch.Tensor:
    """Logit of a probability (clamped to [1e-6, 1 - 1e-6]), float32: texture and opacity logits."""
    p = torch.as_tensor(p, dtype=torch.float32).clamp(1e-6, 1 - 1e-6)
    return torch.log(p / (1 - p))


class SkyModel(torch.nn.Module):
    """Sky colour by view direction: a (3, H, W) lat-long texture of logits, sampled bilinearly.

    Columns span azimuth -pi..pi (wrapping), rows the elevation from the zenith (row 0) down
    to ``SKY_ELEV_MIN``; directions lower than that clamp to the bottom row. Directions are in
    the scene frame, which is a pure translation of the city frame, so the sky never turns with
    the camera (the MapGS "sky rotating the wrong way" bug is a rotation applied twice).
    """

    def __init__(self, height: int = 32, width: int = 128,
                 init_rgb: tuple[float, float, float] = SKY_INIT_RGB):
        super().__init__()
        logits = inverse_sigmoid(torch.tensor(init_rgb, dtype=torch.float32))
        self.texture = torch.nn.Parameter(logits[:, None, None].expand(3, height, width).clone())

    @staticmethod
    def direction_to_grid(dirs: torch.Tensor, width: int) -> torch.Tensor:
        """grid_sample coordinates in [-1, 1] of unit-or-not directions (..., 3) on a W+1 wrapped texture."""
        d = dirs / dirs.norm(dim=-1, keepdim=True).clamp_min(1e-12)
        az = torch.atan2(d[..., 1], d[..., 0])  # -pi..pi
        elev = torch.asin(d[..., 2].clamp(-1.0, 1.0)).clamp_min(SKY_ELEV_MIN)
        # Texture columns 0..W-1 cover azimuth [-pi, pi) at column centres -pi + 2 pi j / W; the
        # padded column W repeats column 0 (azimuth +pi). align_corners=True maps -1..1 to 0..W.
        gx = (az + math.pi) / (2 * math.pi) * 2.0 - 1.0
        gy = (math.pi / 2 - elev) / (math.pi / 2 - SKY_ELEV_MIN) * 2.0 - 1.0
        return torch.stack([gx, gy], -1)

    def forward(self, dirs: torch.Tensor) -> torch.Tensor:
        """RGB in [0, 1] for directions (..., 3)."""
        shape = dirs.shape[:-1]
        tex = torch.cat([self.texture, self.texture[:, :, :1]], dim=2)  # wrap azimuth
        grid = self.direction_to_grid(dirs.reshape(1, -1, 1, 3), self.texture.shape[2]).to(tex.dtype)
        out = F.grid_sample(tex[None], grid, mode="bilinear", padding_mode="border", align_corners=True)
        return torch.sigmoid(out[0, :, :, 0].T).reshape(*shape, 3)


@lru_cache(maxsize=64)
def camera_rays(fx: float, fy: float, cx: float, cy: float, width: int, height: int) -> np.ndarray:
    """(H, W, 3) float64 camera-frame rays (z = 1) through pixel centres (rig convention: centre of pixel u
    is u), computed once per camera model; read-only."""
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    rays = np.stack([(u - cx) / fx, (v - cy) / fy, np.ones_like(u)], -1)
    rays.flags.writeable = False
    return rays


@lru_cache(maxsize=64)
def _pixel_rays_cam(fx: float, fy: float, cx: float, cy: float, width: int, height: int,
                    device: str = "cpu") -> torch.Tensor:
    """:func:`camera_rays` as float32 on ``device`` (the same values on every device)."""
    return torch.tensor(camera_rays(fx, fy, cx, cy, width, height)).float().to(device)


def pixel_rays(cam: CameraSpec, scene_T_cam: F64, device: torch.device | str = "cpu") -> torch.Tensor:
    """(H, W, 3) float32 ray directions in the scene frame (not normalised), on ``device``."""
    K = cam.K
    rays = _pixel_rays_cam(float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]), cam.width,
                           cam.height, str(device))
    R = torch.as_tensor(np.asarray(scene_T_cam)[:3, :3], dtype=torch.float32, device=rays.device)
    return rays @ R.T
