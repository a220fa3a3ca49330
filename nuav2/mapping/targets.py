"""Dense auxiliary targets of MapTRv2: BEV and perspective-view segmentation, and depth.

- BEV: each class's polylines drawn one cell wide into the model's BEV grid (rows = lidar y
  forward, columns = lidar x right; cell centres as in ``grid_sample(align_corners=False)``).
- Perspective view: the polylines lifted onto the ego ground plane (z_ego = 0, nuScenes-style
  ground-level origin) and projected with each camera's ``lidar2img`` onto its stride-8 feature
  grid, clipped at a near plane (the same geometry ``nuav2 viz`` draws with).
- Depth (MapTRv2 supervises its lift with LiDAR depth): the keyframe's LIDAR_TOP sweep projected
  with each camera's ``lidar2img`` (which carries that camera's own ego pose); per feature pixel the
  nearest return's depth bin, -1 where none falls.
"""

from __future__ import annotations

import cv2
import numpy as np

from nuav2.mapping.config import MapModelConfig
from nuav2.viz import densify, ground_points_lidar, project_segments

_SHIFT = 3  # cv2 fixed-point bits: sub-pixel line ends


def _draw(mask: np.ndarray, segments: np.ndarray) -> None:
    """Draw (S, 2, 2) pixel-coordinate segments (pixel centres at integers) one pixel wide."""
    if len(segments) == 0:
        return
    lim = 4 * max(mask.shape)
    seg = np.round(np.clip(segments, -lim, lim) * (1 << _SHIFT)).astype(np.int32)
    for (x0, y0), (x1, y1) in seg:
        cv2.line(mask, (int(x0), int(y0)), (int(x1), int(y1)), 1, 1, cv2.LINE_8, _SHIFT)


def bev_targets(vectors: list[tuple[str, np.ndarray]], cfg: MapModelConfig) -> np.ndarray:
    """(K, rows, cols) uint8 masks of the GT polylines per class."""
    rows, cols = cfg.bev_shape
    hx, hy = cfg.half_extent_xy
    out = np.zeros((len(cfg.classes), rows, cols), np.uint8)
    index = {c: i for i, c in enumerate(cfg.classes)}
    for cls, pts in vectors:
        if cls not in index or len(pts) < 2:
            continue
        p = np.asarray(pts, np.float64)
        px = np.column_stack([(p[:, 0] + hx) / cfg.bev_cell_m - 0.5, (p[:, 1] + hy) / cfg.bev_cell_m - 0.5])
        _draw(out[index[cls]], np.stack([px[:-1], px[1:]], axis=1))
    return out


def pv_targets(
    vectors: list[tuple[str, np.ndarray]],
    lidar2img: np.ndarray,
    lidar2ego: np.ndarray,
    feat_hw: tuple[int, int],
    cfg: MapModelConfig,
) -> np.ndarray:
    """(N, K, h, w) uint8 masks: GT polylines on the ground seen by each camera, on its feature grid."""
    n = len(lidar2img)
    h, w = feat_hw
    out = np.zeros((n, len(cfg.classes), h, w), np.uint8)
    index = {c: i for i, c in enumerate(cfg.classes)}
    lifted = [
        (index[c], ground_points_lidar(densify(p), lidar2ego))
        for c, p in vectors
        if c in index and len(p) >= 2
    ]
    # Feature pixel j is centred on image pixel s * j + (s - 1) / 2 (acts on (uz, vz, z, 1)).
    s = cfg.feat_stride
    off = -(s - 1) / (2.0 * s)
    to_feat = np.array([[1.0 / s, 0, off, 0], [0, 1.0 / s, off, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
    for cam in range(n):
        P = to_feat @ np.asarray(lidar2img[cam], np.float64)
        for k, xyz in lifted:
            _draw(out[cam, k], project_segments(xyz, P))
    return out


def depth_targets(
    points_lidar: np.ndarray,
    lidar2img: np.ndarray,
    img_hw: np.ndarray,
    feat_hw: tuple[int, int],
    cfg: MapModelConfig,
) -> np.ndarray:
    """(N, h, w) int16 depth-bin index of the nearest LiDAR return in each feature pixel, -1 if none."""
    n = len(lidar2img)
    h, w = feat_hw
    out = np.full((n, h * w), np.inf)
    hom = np.column_stack([np.asarray(points_lidar, np.float64)[:, :3], np.ones(len(points_lidar))])
    for cam in range(n):
        p = hom @ np.asarray(lidar2img[cam], np.float64).T
        z = p[:, 2]
        keep = (z >= cfg.depth_min_m) & (z < cfg.depth_max_m)
        u, v, z = p[keep, 0] / z[keep], p[keep, 1] / z[keep], z[keep]
        inside = (u >= -0.5) & (v >= -0.5) & (u < img_hw[cam][1] - 0.5) & (v < img_hw[cam][0] - 0.5)
        s = cfg.feat_stride
        cell = (np.floor((v[inside] + 0.5) / s) * w + np.floor((u[inside] + 0.5) / s)).astype(np.int64)
        np.minimum.at(out[cam], cell, z[inside])
    step = (cfg.depth_max_m - cfg.depth_min_m) / cfg.depth_bins
    bins = np.where(np.isfinite(out), np.floor((out - cfg.depth_min_m) / step), -1)
    return np.clip(bins, -1, cfg.depth_bins - 1).astype(np.int16).reshape(n, h, w)
