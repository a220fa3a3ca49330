"""Render above the training resolution without eroding the scene.

The rasterizer blurs every projected Gaussian by ``EPS2D`` pixels² (3DGS's low-pass filter), so training
fits Gaussians that look right *with* that blur at the training images' pixel size. Rendered with finer
pixels (a 1600 x 900 nuScenes camera from a reconstruction trained at 256 px wide: about 6x the focal
length in pixels) the blur shrinks with the pixel and sub-pixel Gaussians turn into thin specks with
gaps between them (Mip-Splatting's "erosion"). Adding to each Gaussian the isotropic 3D variance that
projects to the training blur's extra size at its depth restores its trained look; at or below the
training resolution nothing changes (training renders never reach this path).
"""

from __future__ import annotations

import numpy as np
import torch

from nuav2.geometry import F64, T_inverse
from nuav2.splat.constants import EPS2D


def focal_px(K: np.ndarray) -> float:
    """A camera's focal length in pixels (geometric mean of fx and fy)."""
    K = np.asarray(K, np.float64)
    return float(np.sqrt(abs(K[0, 0] * K[1, 1])))


def widen_to_training_footprint(log_scales: torch.Tensor, means: torch.Tensor, scene_T_cam: F64,
                                target_focal_px: float, train_focal_px: float | None) -> torch.Tensor:
    """``log_scales`` widened so that each Gaussian, rendered by a camera of ``target_focal_px`` at
    ``scene_T_cam``, keeps the angular blur it was trained with (cameras of ``train_focal_px`` or less).

    Extra 2D variance in target pixels ``EPS2D * (r² - 1)`` (r = target / training focal) is, at depth z,
    an isotropic 3D variance ``EPS2D * (1/f_train² - 1/f_target²) * z²``; opacity is left alone, as the
    training blur left it. Unchanged (the same tensor) when the target is not finer than training."""
    if train_focal_px is None or not target_focal_px > train_focal_px or len(means) == 0:
        return log_scales
    cam_T_scene = torch.as_tensor(T_inverse(np.asarray(scene_T_cam, np.float64)), dtype=means.dtype,
                                  device=means.device)
    z = (means @ cam_T_scene[2, :3] + cam_T_scene[2, 3]).clamp_min(1e-3)
    k = EPS2D * (1.0 / train_focal_px**2 - 1.0 / target_focal_px**2)
    log_var = torch.log(k * z * z)[:, None]
    return 0.5 * torch.logaddexp(2.0 * log_scales, log_var)  # log sqrt(s² + var), no overflow
