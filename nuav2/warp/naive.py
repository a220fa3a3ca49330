"""Naive baseline: the source camera looking most nearly the same way, resized to the target intrinsics.

No geometry beyond the optical axes: the source image is resampled through ``K_src K_tgt^-1``
(same viewing direction per pixel as if the two cameras shared a pose), so it is what a user
gets by "just resizing AV2 images to nuScenes intrinsics". The warp must beat it.
"""

from __future__ import annotations

import cv2
import numpy as np

from nuav2.geometry import F64
from nuav2.rig import CameraSpec, Rig


def optical_axis_angle(a_ego_T_cam: F64, b_ego_T_cam: F64) -> float:
    """Angle (rad) between two cameras' optical (+z) axes, both given in one vehicle frame orientation."""
    za = np.asarray(a_ego_T_cam)[:3, 2]
    zb = np.asarray(b_ego_T_cam)[:3, 2]
    c = float(za @ zb / (np.linalg.norm(za) * np.linalg.norm(zb)))
    return float(np.arccos(np.clip(c, -1.0, 1.0)))


def closest_source_camera(target: CameraSpec, source_rig: Rig) -> CameraSpec:
    """The source camera whose optical axis is closest to the target's (vehicle frames share axes)."""
    if not source_rig.cameras:
        raise ValueError(f"source rig {source_rig.name!r} has no cameras")
    angles = [optical_axis_angle(target.ego_T_cam, c.ego_T_cam) for c in source_rig.cameras]
    return source_rig.cameras[int(np.argmin(angles))]


def resize_to_intrinsics(image: np.ndarray, source: CameraSpec,
                         target: CameraSpec) -> tuple[np.ndarray, np.ndarray]:
    """Resample ``image`` (source camera) to the target's size and K; returns (image, covered mask).

    Target pixel (u, v) takes the source pixel ``K_src K_tgt^-1 [u, v, 1]`` (bilinear); pixels
    outside the source image are uncovered (value 0).
    """
    if image.shape[:2] != (source.height, source.width):
        raise ValueError(f"{source.channel}: image is {image.shape[1]}x{image.shape[0]}, "
                         f"calibration says {source.width}x{source.height}")
    H = source.K @ np.linalg.inv(target.K)
    u, v = np.meshgrid(np.arange(target.width, dtype=np.float64), np.arange(target.height, dtype=np.float64))
    p = np.stack([u, v, np.ones_like(u)], -1) @ H.T
    su, sv = p[..., 0] / p[..., 2], p[..., 1] / p[..., 2]
    covered = (su >= -0.5) & (su <= source.width - 0.5) & (sv >= -0.5) & (sv <= source.height - 0.5)
    out = cv2.remap(image, su.astype(np.float32), sv.astype(np.float32), cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_REPLICATE)
    out[~covered] = 0
    return out, covered
