"""The ground under the scene and the flat seeds on it that carry lane paint between LiDAR rings."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from nuav2.geometry import F64, T_inverse
from nuav2.scene import SceneLog

if TYPE_CHECKING:
    from nuav2.splat.init import InitConfig


class GroundSurface:
    """Ground height in the scene frame: the log's ground-height raster where it has a value,
    else the nearest ego pose's height minus the rig's origin height."""

    def __init__(self, scene: SceneLog, scene_T_city: F64) -> None:
        from scipy.spatial import cKDTree

        self.city_T_scene = T_inverse(scene_T_city)
        self.path = (scene_T_city[None] @ scene.city_T_ego)[:, :3, 3]
        self.tree = cKDTree(self.path[:, :2])
        self.origin_height = scene.rig.origin_height_m
        self.raster = scene.ground_height

    def __call__(self, xy_scene: F64) -> F64:
        xy_scene = np.asarray(xy_scene, np.float64).reshape(-1, 2)
        if len(xy_scene) == 0:
            return np.zeros(0)
        nearest = np.asarray(self.tree.query(xy_scene, k=1)[1], np.int64)
        z = self.path[nearest, 2] - self.origin_height
        if self.raster is not None:
            z_city = self.raster.height_at(xy_scene + self.city_T_scene[:2, 3])
            ok = np.isfinite(z_city)
            z[ok] = z_city[ok] - self.city_T_scene[2, 3]
        return z


def ground_seeds(ground: GroundSurface, occupied_xy_scene: F64, cfg: InitConfig) -> tuple[F64, np.ndarray]:
    """Grid points on the ground surface within ``ground_radius_m`` of the ego path, skipping cells where
    LiDAR shows something standing (buildings, parked cars): (N, 3) scene points and their (N, 2) integer
    grid cells (cell (i, j) is centred at ((i + 0.5) s, (j + 0.5) s), so coarser blocks align)."""
    if cfg.ground_spacing_m <= 0:
        return np.zeros((0, 3)), np.zeros((0, 2), np.int64)
    from scipy.spatial import cKDTree

    path = ground.path
    s, r = cfg.ground_spacing_m, cfg.ground_radius_m
    lo = np.floor((path[:, :2].min(0) - r) / s).astype(np.int64)
    hi = np.ceil((path[:, :2].max(0) + r) / s).astype(np.int64)
    gi, gj = np.meshgrid(np.arange(lo[0], hi[0]), np.arange(lo[1], hi[1]))
    cell = np.column_stack([gi.ravel(), gj.ravel()])
    xy = (cell + 0.5) * s
    near = np.asarray(ground.tree.query(xy, k=1)[0]) <= r
    xy, cell = xy[near], cell[near]
    if len(occupied_xy_scene) and len(xy):
        d, _ = cKDTree(occupied_xy_scene).query(xy, k=1)
        free = d > max(s, 0.3)
        xy, cell = xy[free], cell[free]
    return np.column_stack([xy, ground(xy)]), cell


def occupied_cells(points_scene: F64, ground_z_fn, clear_height: float) -> F64:
    """xy of background LiDAR points standing higher than ``clear_height`` above the ground."""
    if len(points_scene) == 0:
        return np.zeros((0, 2))
    high = points_scene[:, 2] - ground_z_fn(points_scene[:, :2]) > clear_height
    return points_scene[high, :2]
