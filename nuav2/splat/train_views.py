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
from nuav2.threads import ordered_thread_map


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


def nearest_sweep(sweep_ns: np.ndarray, timestamp_ns: int) -> int:
    """Index of the LiDAR sweep (times ``sweep_ns``) nearest a camera timestamp (the earlier on a tie)."""
    return int(np.argmin(np.abs(sweep_ns - timestamp_ns)))


def lidar_depth_samples(scene: SceneLog, view: SourceView, scene_T_city: F64, max_points: int = 20_000,
                        max_depth_m: float = 150.0, scene_pts: np.ndarray | None = None) -> np.ndarray:
    """LiDAR z-depth in a view from the sweep nearest its timestamp: (M, 3) u, v, z float32.

    ``scene_pts``: that sweep already read, in the scene frame (:func:`lidar_depth_by_view` reads
    each sweep once for all the views that share it)."""
    if not scene.lidar_sweeps:
        return np.zeros((0, 3), np.float32)
    if scene_pts is None:
        scene_pts = sweep_in_scene(scene, nearest_sweep(scene.sweep_timestamps_ns, view.timestamp_ns),
                                   scene_T_city)
    cam_T_scene = T_inverse(scene_T_city @ view.city_T_cam)
    proj = project(scene_pts, view.cam, cam_T_scene, near=0.5)
    ok = proj.z < max_depth_m
    uvz = np.column_stack([proj.u[ok], proj.v[ok], proj.z[ok]]).astype(np.float32)
    pv = np.clip(np.round(uvz[:, 1]).astype(int), 0, view.cam.height - 1)
    pu = np.clip(np.round(uvz[:, 0]).astype(int), 0, view.cam.width - 1)
    uvz = uvz[view.valid[pv, pu]]
    return uvz[:max_points]


def sweep_in_scene(scene: SceneLog, index: int, scene_T_city: F64) -> np.ndarray:
    """Sweep ``index``'s points in the scene frame, float64 (N, 3)."""
    ref = scene.lidar_sweeps[index]
    scene_T_ego = scene_T_city @ scene.city_T_ego_at(int(ref.timestamp_ns))
    return scene.sweep(ref).xyz_ego @ scene_T_ego[:3, :3].T + scene_T_ego[:3, 3]


def lidar_depth_by_view(scene: SceneLog, views: list[SourceView], scene_T_city: F64,
                        threads: int = 1) -> list[np.ndarray]:
    """:func:`lidar_depth_samples` of every view, in order, reading each sweep once (the views that
    share a nearest sweep are done together: the 7 ring cameras of a frame share one) on
    ``threads`` threads."""
    if not scene.lidar_sweeps:
        return [np.zeros((0, 3), np.float32) for _ in views]
    sweep_ns = scene.sweep_timestamps_ns
    groups: dict[int, list[int]] = {}
    for i, v in enumerate(views):
        groups.setdefault(nearest_sweep(sweep_ns, v.timestamp_ns), []).append(i)

    def one_sweep(item: tuple[int, list[int]]) -> list[tuple[int, np.ndarray]]:
        pts = sweep_in_scene(scene, item[0], scene_T_city)
        return [(i, lidar_depth_samples(scene, views[i], scene_T_city, scene_pts=pts)) for i in item[1]]

    out: list[np.ndarray | None] = [None] * len(views)
    for done in ordered_thread_map(one_sweep, sorted(groups.items()), threads):
        for i, uvz in done:
            out[i] = uvz
    return out  # type: ignore[return-value]
