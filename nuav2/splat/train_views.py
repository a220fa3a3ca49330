"""A training view's targets on the training device: image, valid and sky masks, LiDAR depth samples.

Images and masks are resized per pyramid level on the CPU (OpenCV) once, then kept as tensors on
the device the scene trains on, so a step moves no pixels between devices.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
import torch

from nuav2.geometry import F64, T_inverse
from nuav2.scene import SceneLog
from nuav2.splat.views import SourceView, project


@dataclass
class ViewData:
    """A training view's targets at the training resolution: image, valid mask, sky, LiDAR depth."""

    view: SourceView
    sky: np.ndarray  # (H, W) bool
    depth_uvz: np.ndarray  # (M, 3) float32, rig pixel convention
    device: torch.device = field(default_factory=lambda: torch.device("cpu"))
    _levels: dict = field(default_factory=dict, repr=False)

    def at(self, level: float) -> tuple:
        """(camera, image, valid, sky, depth samples) as tensors on ``device`` at a pyramid level."""
        if level not in self._levels:
            cam = self.view.cam.scaled(level) if level != 1.0 else self.view.cam
            img = self.view.image_u8()
            valid = self.view.valid
            sky = self.sky
            if level != 1.0:
                size = (cam.width, cam.height)
                img = cv2.resize(img, size, interpolation=cv2.INTER_AREA)
                valid = cv2.resize(valid.astype(np.float32), size, interpolation=cv2.INTER_AREA) > 0.999
                sky = cv2.resize(sky.astype(np.float32), size, interpolation=cv2.INTER_AREA) > 0.999
            uvz = self.depth_uvz.copy()
            sx, sy = cam.width / self.view.cam.width, cam.height / self.view.cam.height
            uvz[:, 0] = (uvz[:, 0] + 0.5) * sx - 0.5
            uvz[:, 1] = (uvz[:, 1] + 0.5) * sy - 0.5
            arrays = (np.ascontiguousarray(img), valid, sky, uvz)
            self._levels[level] = (cam, *(torch.from_numpy(a).to(self.device) for a in arrays))
        cam, img, valid, sky, uvz = self._levels[level]
        return cam, img.float() / 255.0, valid, sky, uvz


def lidar_depth_samples(scene: SceneLog, view: SourceView, scene_T_city: F64, max_points: int = 20_000,
                        max_depth_m: float = 150.0, sweep_cache: dict | None = None) -> np.ndarray:
    """LiDAR z-depth in a view from the sweep nearest its timestamp: (M, 3) u, v, z float32.

    ``sweep_cache`` (sweep timestamp -> scene-frame points) avoids re-reading a sweep that
    several views share."""
    if not scene.lidar_sweeps:
        return np.zeros((0, 3), np.float32)
    ts = scene.sweep_timestamps_ns
    ref = scene.lidar_sweeps[int(np.argmin(np.abs(ts - view.timestamp_ns)))]
    key = int(ref.timestamp_ns)
    if sweep_cache is None or key not in sweep_cache:
        scene_T_ego = scene_T_city @ scene.city_T_ego_at(key)
        pts = scene.sweep(ref).xyz_ego @ scene_T_ego[:3, :3].T + scene_T_ego[:3, 3]
        if sweep_cache is not None:
            sweep_cache.clear()  # views come grouped by camera, sorted by time: keep one sweep
            sweep_cache[key] = pts
    else:
        pts = sweep_cache[key]
    cam_T_scene = T_inverse(scene_T_city @ view.city_T_cam)
    proj = project(pts, view.cam, cam_T_scene, near=0.5)
    ok = proj.z < max_depth_m
    uvz = np.column_stack([proj.u[ok], proj.v[ok], proj.z[ok]]).astype(np.float32)
    pv = np.clip(np.round(uvz[:, 1]).astype(int), 0, view.cam.height - 1)
    pu = np.clip(np.round(uvz[:, 0]).astype(int), 0, view.cam.width - 1)
    uvz = uvz[view.valid[pv, pu]]
    return uvz[:max_points]
