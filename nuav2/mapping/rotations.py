"""Map GT of every training keyframe in rotated BEV frames, for rotation augmentation.

A few synthetic worlds give a few nearly identical views each; a model can learn them as a map
prior (where lines are in the patch) instead of reading the images. Rotating the LIDAR_TOP frame
about its z axis by ``theta`` breaks that prior while keeping every pixel's ray honest:
``lidar2img`` becomes ``lidar2img @ R(theta)^-1`` (same pixel, same depth, rotated 3-D point),
and the GT is the map cut out of the *rotated* patch by the same vectorizer ``nuav2.maptr`` uses
(``MapPatch.from_pose(global_T_lidar @ R^-1)``), so elements entering the patch's corners are
there, not missing as they would be if the unrotated patch's vectors were rotated and re-clipped.
The GT is computed once per keyframe and angle (at data-load time, cached with the tensors);
training picks one angle per sample.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from nuav2.mapping.config import MapModelConfig
from nuav2.mapping.targets import bev_targets


def rotation_T(deg: float) -> np.ndarray:
    """4x4 rotation about LIDAR_TOP's z axis: augmented point = R @ original point."""
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    T = np.eye(4)
    T[:2, :2] = [[c, -s], [s, c]]
    return T


def rotated_targets(dataset, index: int, deg: float, cfg: MapModelConfig) -> dict:
    """Labels, fixed-point ordering variants and BEV target of keyframe ``index`` of a
    ``MapSampleDataset`` in the LIDAR_TOP frame rotated by ``deg``."""
    vectors, labels, _, shifts = dataset.fixed_point_targets(index, np.linalg.inv(rotation_T(deg)))
    return {
        "labels": torch.from_numpy(labels),
        "shifts": torch.from_numpy(shifts).float(),
        "bev": torch.from_numpy(bev_targets(vectors, cfg)),
    }


def rotate_batch(batch: dict, rotated: list[dict | None], degs: list[float]) -> dict:
    """The batch with sample b seen in its frame rotated by ``degs[b]``: ``rotated[b]`` holds that
    frame's GT (``rotated_targets``); ``None`` (angle 0) keeps the sample as it is."""
    out = dict(batch)
    inv = torch.stack([torch.from_numpy(np.linalg.inv(rotation_T(d))).float() for d in degs])
    out["lidar2img"] = batch["lidar2img"] @ inv[:, None]
    out["gt_labels"] = [r["labels"] if r else g for r, g in zip(rotated, batch["gt_labels"])]
    out["gt_shifts"] = [r["shifts"] if r else g for r, g in zip(rotated, batch["gt_shifts"])]
    out["bev_target"] = torch.stack([r["bev"] if r else t for r, t in zip(rotated, batch["bev_target"])])
    return out
