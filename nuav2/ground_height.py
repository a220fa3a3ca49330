"""How high the ego origin sits above the ground, measured per log from poses and the ground raster.

Frame alignment (paper eq. 1) shifts the source vehicle frame by this height; the rig spec
carries a nominal value (AV2: 0.32 m) and this measures it, so a log whose value is off can
be spotted.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nuav2.scene import SceneLog


@dataclass(frozen=True)
class OriginHeightEstimate:
    """Statistics of (pose z - ground z) over the ``n`` poses with a known ground height."""

    mean_m: float
    std_m: float
    min_m: float
    max_m: float
    n: int


def origin_heights(scene: SceneLog) -> np.ndarray:
    """Per-pose ego-origin height above the ground raster (NaN where the raster has no value)."""
    if scene.ground_height is None:
        raise ValueError(f"log {scene.log_id}: no ground-height raster, cannot measure the ego origin height")
    city_xyz_ego = scene.city_T_ego[:, :3, 3]
    return city_xyz_ego[:, 2] - scene.ground_height.height_at(city_xyz_ego[:, :2])


def estimate_origin_height(scene: SceneLog) -> OriginHeightEstimate:
    """Mean/std/range of the ego origin's height above ground over all poses with finite ground."""
    h = origin_heights(scene)
    h = h[np.isfinite(h)]
    if len(h) == 0:
        raise ValueError(f"log {scene.log_id}: the ground raster has no value under any of its "
                         f"{len(scene.city_T_ego)} poses")
    return OriginHeightEstimate(mean_m=float(h.mean()), std_m=float(h.std()), min_m=float(h.min()),
                                max_m=float(h.max()), n=int(len(h)))
