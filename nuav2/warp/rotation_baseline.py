"""Rotation-homography baseline: source images turned into the target view as if all scene points were
at infinity (``x_t ~ K_t R_t_s K_s^-1 x_s``), the camera-alignment baseline of the literature.

It uses each camera's real orientation (city poses at the target time and at the source image's
own time) but no depth: it is exact for the sky and far scenery and wrong by the parallax of the
camera offset for near things. The warp (``nuav2.warp.provider``) must beat it. With several
sources each target pixel takes the source whose optical axis is closest to its ray among those
that see it (a panorama mosaic); with one it is the single closest-camera baseline.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from nuav2.geometry import F64
from nuav2.rig import CameraSpec, Rig


@dataclass(frozen=True)
class RotationSource:
    """One source image with its camera and city pose at the image's own timestamp."""

    image: np.ndarray  # (H, W, 3), uint8 or float32
    camera: CameraSpec
    city_T_cam: F64

    def __post_init__(self) -> None:
        c = self.camera
        if self.image.shape[:2] != (c.height, c.width):
            raise ValueError(f"{c.channel}: image is {self.image.shape[1]}x{self.image.shape[0]}, "
                             f"calibration says {c.width}x{c.height}")


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


def rotation_homography(source: CameraSpec, city_T_src: F64, target: CameraSpec, city_T_tgt: F64) -> F64:
    """3x3 ``H = K_t R_t_s K_s^-1`` mapping source pixels to target pixels for points at infinity
    (``R_t_s``: source camera axes to target camera axes; translations play no part)."""
    R_t_s = np.asarray(city_T_tgt, np.float64)[:3, :3].T @ np.asarray(city_T_src, np.float64)[:3, :3]
    return target.K @ R_t_s @ np.linalg.inv(source.K)


def _pixel_grid(camera: CameraSpec) -> F64:
    """(H, W, 3) homogeneous pixel centres (OpenCV: pixel (u, v) is centred at (u, v))."""
    u, v = np.meshgrid(np.arange(camera.width, dtype=np.float64), np.arange(camera.height, dtype=np.float64))
    return np.stack([u, v, np.ones_like(u)], -1)


def rotate_into_target(sources: Sequence[RotationSource], target: CameraSpec,
                       city_T_tgt: F64) -> tuple[np.ndarray, np.ndarray]:
    """(image in the target view with the sources' dtype, covered mask): each pixel bilinear from the
    source whose optical axis is closest to the pixel's ray among the sources that see that ray (in
    front of the camera, inside the image, off the ego body). Uncovered pixels are 0."""
    if not sources:
        raise ValueError(f"{target.channel}: no source image to rotate into the target view")
    grid = _pixel_grid(target)
    rays_tgt = grid @ np.linalg.inv(target.K).T  # target camera axes, z = 1
    rays_city = rays_tgt @ np.asarray(city_T_tgt, np.float64)[:3, :3].T
    rays_city /= np.linalg.norm(rays_city, axis=-1, keepdims=True)
    out = np.zeros((target.height, target.width, 3), sources[0].image.dtype)
    covered = np.zeros((target.height, target.width), bool)
    best_cos = np.full((target.height, target.width), -np.inf)
    for src in sources:
        H_s_t = np.linalg.inv(rotation_homography(src.camera, src.city_T_cam, target, city_T_tgt))
        p = grid @ H_s_t.T
        with np.errstate(divide="ignore", invalid="ignore"):
            su, sv = p[..., 0] / p[..., 2], p[..., 1] / p[..., 2]
        sees = (p[..., 2] > 0) & (su >= -0.5) & (su <= src.camera.width - 0.5) & (sv >= -0.5) & (
            sv <= src.camera.height - 0.5)
        if src.camera.ego_mask_polygons and np.any(sees):
            body = src.camera.ego_mask()
            rows = np.clip(np.rint(sv[sees]).astype(int), 0, src.camera.height - 1)
            cols = np.clip(np.rint(su[sees]).astype(int), 0, src.camera.width - 1)
            sees[sees] = ~body[rows, cols]
        cos = rays_city @ np.asarray(src.city_T_cam, np.float64)[:3, 2]
        take = sees & (cos > best_cos)
        if not np.any(take):
            continue
        mapx = np.where(take, su, -1.0).astype(np.float32)
        mapy = np.where(take, sv, -1.0).astype(np.float32)
        img = cv2.remap(np.ascontiguousarray(src.image), mapx, mapy, cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_REPLICATE)
        out[take] = img[take]
        covered |= take
        best_cos = np.where(take, cos, best_cos)
    return out, covered
