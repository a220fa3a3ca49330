"""MapTR-format vectors traced from the BEV segmentation head (HDMapNet-style post-processing).

Why: at CPU scale the dense BEV segmentation learns from a few hundred steps and generalises to
unseen worlds long before the set-prediction decoder does (DETR-style decoders converge slowly),
so the segmentation, thinned and traced into polylines, gives a second MapTR result file of the
same model, scored by the same ``nuav2 eval``. Per class: threshold the cell probabilities, thin
the mask to one-cell-wide ridges, and peel the ridge graph into polylines (the longest geodesic
path, then the longest of what is left, ...), each resampled to ``num_points`` and scored by its
mean probability.
"""

from __future__ import annotations

from collections import deque

import cv2
import numpy as np
import torch

from nuav2.mapping.config import MapModelConfig

_NEIGHBOURS = [(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)]


def _farthest(start: tuple[int, int], cells: set) -> tuple[tuple[int, int], dict]:
    """BFS over 8-connected ``cells`` from ``start``: the farthest cell and the parent links."""
    parent = {start: None}
    queue, last = deque([start]), start
    while queue:
        last = queue.popleft()
        r, c = last
        for dr, dc in _NEIGHBOURS:
            n = (r + dr, c + dc)
            if n in cells and n not in parent:
                parent[n] = last
                queue.append(n)
    return last, parent


def trace_paths(skeleton: np.ndarray, min_cells: int) -> list[np.ndarray]:
    """Polylines (K, 2) of (row, col) cells covering a one-cell-wide skeleton: per connected piece its
    longest path (two BFS sweeps), then again on the cells farther than one cell from it."""
    cells = set(map(tuple, np.argwhere(skeleton)))
    paths = []
    while cells:
        seed = next(iter(cells))
        a, _ = _farthest(seed, cells)
        b, parent = _farthest(a, cells)
        path, node = [], b
        while node is not None:
            path.append(node)
            node = parent[node]
        component = set(parent)
        near = {(r + dr, c + dc) for r, c in path for dr in (-1, 0, 1) for dc in (-1, 0, 1)}
        if len(path) >= min_cells:
            paths.append(np.asarray(path, np.float64))
            cells -= component & near
        else:  # too short to be an element: drop the whole piece
            cells -= component
    return paths


def resample(points: np.ndarray, num: int) -> np.ndarray:
    """``num`` points evenly spaced along the polyline."""
    seg = np.linalg.norm(np.diff(points, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    t = np.linspace(0.0, s[-1], num)
    return np.column_stack([np.interp(t, s, points[:, i]) for i in range(points.shape[1])])


def seg_vectors(
    logits: torch.Tensor, cfg: MapModelConfig, threshold: float = 0.5, min_length_m: float = 2.0
) -> list[tuple[str, np.ndarray, float]]:
    """One sample's BEV logits (K, rows, cols) -> [(class, (num_points, 2) LIDAR_TOP metres, score)]."""
    prob = torch.sigmoid(logits).double().numpy()
    hx, hy = cfg.half_extent_xy
    min_cells = max(2, int(round(min_length_m / cfg.bev_cell_m)))
    out = []
    for k, cls in enumerate(cfg.classes):
        mask = (prob[k] > threshold).astype(np.uint8)
        if mask.sum() < min_cells:
            continue
        skeleton = cv2.ximgproc.thinning(mask * 255) > 0
        for path in trace_paths(skeleton, min_cells):
            r, c = path[:, 0].astype(int), path[:, 1].astype(int)
            score = float(prob[k][r, c].mean())
            # cell centres -> metres (columns along lidar x = right, rows along lidar y = forward)
            xy = np.column_stack(
                [(path[:, 1] + 0.5) * cfg.bev_cell_m - hx, (path[:, 0] + 0.5) * cfg.bev_cell_m - hy]
            )
            out.append((cls, resample(xy, cfg.num_points), score))
    return out
