"""The ground under the scene and the flat seeds on it that carry lane paint between LiDAR rings."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from nuav2.cells import cell_indices, unique_cells
from nuav2.geometry import F64, T_inverse
from nuav2.scene import SceneLog
from nuav2.terrain import bilinear_height

if TYPE_CHECKING:
    from nuav2.splat.init import InitConfig


class GroundSurface:
    """Ground height in the scene frame, from the best source that has a value at each point:

    1. the log's ground-height raster, bilinear between cell centres (:mod:`nuav2.terrain`);
    2. off the raster (it covers the drivable area and a margin), LiDAR ground returns: per
       ``lidar_cell_m`` cell the 10th percentile height of the points near the expected ground
       (the next source), reaching out ``lidar_reach_m`` to the nearest such cell;
    3. else the nearest raster cell within ``raster_reach_m``;
    4. else the ground plane under the nearest ego pose, tilted with the ego (grades and cross-fall
       continue past the last pose instead of flattening into a floating or sunken road).
    """

    def __init__(self, scene: SceneLog, scene_T_city: F64, lidar_scene: F64 | None = None,
                 lidar_cell_m: float = 1.0, lidar_reach_m: float = 2.0, raster_reach_m: float = 10.0,
                 radius_m: float = 80.0) -> None:
        from scipy.spatial import cKDTree

        self.city_T_scene = T_inverse(scene_T_city)
        scene_T_ego = scene_T_city[None] @ scene.city_T_ego
        self.path = scene_T_ego[:, :3, 3]
        self.tree = cKDTree(self.path[:, :2])
        self.origin_height = scene.rig.origin_height_m
        up = scene_T_ego[:, :3, 2]
        self.normal = up / np.linalg.norm(up, axis=1, keepdims=True)
        self.foot = self.path - self.origin_height * self.normal
        self.raster = scene.ground_height
        self.raster_reach_m = raster_reach_m
        self.raster_cells = self._raster_cells(radius_m) if self.raster is not None else None
        self.lidar_cells: tuple[object, np.ndarray] | None = None
        self.lidar_reach_m = lidar_reach_m
        if lidar_scene is not None and len(lidar_scene):
            self.lidar_cells = self._lidar_ground(np.asarray(lidar_scene, np.float64), lidar_cell_m)

    def plane(self, xy_scene: F64) -> F64:
        """Height of the ground plane under the nearest ego pose (tilted with the ego)."""
        k = np.asarray(self.tree.query(xy_scene, k=1)[1], np.int64)
        n, f = self.normal[k], self.foot[k]
        dx, dy = xy_scene[:, 0] - f[:, 0], xy_scene[:, 1] - f[:, 1]
        return f[:, 2] - (n[:, 0] * dx + n[:, 1] * dy) / n[:, 2]

    def raster_height(self, xy_scene: F64) -> F64:
        if self.raster is None:
            return np.full(len(xy_scene), np.nan)
        return bilinear_height(self.raster, xy_scene + self.city_T_scene[:2, 3]) - self.city_T_scene[2, 3]

    def _raster_cells(self, radius_m: float) -> tuple[object, np.ndarray] | None:
        """Scene xy and height of the raster's valid cells within ``radius_m`` of the path's bounding box."""
        from scipy.spatial import cKDTree

        r = self.raster
        lo = self.path[:, :2].min(0) - radius_m + self.city_T_scene[:2, 3]
        hi = self.path[:, :2].max(0) + radius_m + self.city_T_scene[:2, 3]
        corners = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [lo[0], hi[1]], [hi[0], hi[1]]])
        p = r.s * (corners @ r.R.T + r.t)
        c0, r0 = np.clip(np.floor(p.min(0)).astype(int), 0, [r.heights.shape[1], r.heights.shape[0]])
        c1, r1 = np.clip(np.ceil(p.max(0)).astype(int), 0, [r.heights.shape[1], r.heights.shape[0]])
        rows, cols = np.nonzero(np.isfinite(r.heights[r0:r1, c0:c1]))
        if len(rows) == 0:
            return None
        pix = np.column_stack([cols + c0 + 0.5, rows + r0 + 0.5]) / r.s - r.t  # = R (xy); R is a rotation
        xy_city = pix @ r.R
        z = r.heights[rows + r0, cols + c0].astype(np.float64) - self.city_T_scene[2, 3]
        return cKDTree(xy_city - self.city_T_scene[:2, 3]), z

    def _nearest(self, cells: tuple[object, np.ndarray] | None, xy: F64, reach: float) -> F64:
        if cells is None or len(xy) == 0:
            return np.full(len(xy), np.nan)
        tree, z = cells
        d, i = tree.query(xy, k=1)
        return np.where(np.asarray(d) <= reach, z[np.asarray(i)], np.nan)

    def _lidar_ground(self, pts: F64, cell_m: float) -> tuple[object, np.ndarray]:
        from scipy.spatial import cKDTree

        expect = self.raster_height(pts[:, :2])
        miss = ~np.isfinite(expect)
        expect[miss] = self._nearest(self.raster_cells, pts[miss, :2], self.raster_reach_m)
        miss = ~np.isfinite(expect)
        expect[miss] = self.plane(pts[miss, :2])
        near = (pts[:, 2] > expect - 1.0) & (pts[:, 2] < expect + 0.5)
        pts = pts[near]
        if len(pts) == 0:
            return cKDTree(np.zeros((1, 2))), np.full(1, np.nan)
        first, inv, _ = unique_cells(pts[:, :2], cell_m)
        uniq = cell_indices(pts[first, :2], cell_m)
        order = np.lexsort((pts[:, 2], inv))
        starts = np.searchsorted(inv[order], np.arange(len(uniq)))
        counts = np.bincount(inv, minlength=len(uniq))
        low = pts[order[starts + (0.1 * (counts - 1)).astype(np.int64)], 2]  # 10th percentile per cell
        return cKDTree((uniq + 0.5) * cell_m), low

    def __call__(self, xy_scene: F64) -> F64:
        xy_scene = np.asarray(xy_scene, np.float64).reshape(-1, 2)
        if len(xy_scene) == 0:
            return np.zeros(0)
        z = self.raster_height(xy_scene)
        sources = ((self.lidar_cells, self.lidar_reach_m), (self.raster_cells, self.raster_reach_m))
        for cells, reach in sources:
            miss = ~np.isfinite(z)
            if miss.any():
                z[miss] = self._nearest(cells, xy_scene[miss], reach)
        miss = ~np.isfinite(z)
        if miss.any():
            z[miss] = self.plane(xy_scene[miss])
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


def fill_unseen_ground(xyz_scene: F64, rgb: np.ndarray, seen: np.ndarray, reach_m: float,
                       neighbours: int) -> tuple[np.ndarray, np.ndarray]:
    """Colours for ground seeds no source image saw: the per-channel median of the ``neighbours`` nearest
    seen ground seeds, for unseen seeds within ``reach_m`` of one. Returns (indices of the filled seeds,
    their (M, 3) colours).

    A target camera looks where the source cameras never did (behind an ego that waits at a junction,
    under its own body): without ground there, the render shows the sky's colour on the road. The
    median keeps a lane line at the edge of the seen area from being smeared across the hole.
    """
    unseen = np.flatnonzero(~seen)
    if reach_m <= 0 or not len(unseen) or not seen.any():
        return np.zeros(0, np.int64), np.zeros((0, 3))
    from scipy.spatial import cKDTree

    seen_idx = np.flatnonzero(seen)
    tree = cKDTree(xyz_scene[seen_idx, :2])
    k = min(neighbours, len(seen_idx))
    d, j = tree.query(xyz_scene[unseen, :2], k=k)
    d, j = d.reshape(len(unseen), k), j.reshape(len(unseen), k)
    near = d[:, 0] <= reach_m
    colours = np.median(rgb[seen_idx[j[near]]], axis=1)
    return unseen[near], colours
