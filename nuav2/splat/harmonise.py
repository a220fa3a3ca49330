"""Source images at one reference exposure: the log's per-image gains and per-camera vignetting solved
from background seeds seen by several images (:mod:`nuav2.exposure`), set on the views before
anything reads their colours (seed colours, sky masks and texture, training targets)."""

from __future__ import annotations

import numpy as np

from nuav2.exposure import ExposureConfig, ExposureModel, Observations, observe, solve_exposure
from nuav2.geometry import F64, T_inverse
from nuav2.splat.views import SourceView


def solve_view_exposure(views: list[SourceView], points_scene: F64, scene_T_city: F64,
                        cfg: ExposureConfig | None = None, *, max_points: int = 30_000,
                        seed: int = 0) -> ExposureModel:
    """Exposure model over ``views`` (indexed by ``SourceView.index``, cameras by channel name order)
    from their raw colours at (a subsample of) static ``points_scene``."""
    cfg = cfg or ExposureConfig()
    rng = np.random.default_rng(seed)
    if len(points_scene) > max_points:
        points_scene = points_scene[np.sort(rng.choice(len(points_scene), max_points, replace=False))]
    channels = sorted({v.channel for v in views})
    n_img = max((v.index for v in views), default=-1) + 1
    camera_of_image = np.zeros(n_img, np.int64)
    obs = Observations()
    for v in views:
        camera_of_image[v.index] = channels.index(v.channel)
        cam_T_scene = T_inverse(scene_T_city @ v.city_T_cam)
        idx, rgb, rho2 = observe(points_scene, v.cam.K, v.cam.width, v.cam.height, cam_T_scene,
                                 v.raw_image_u8(), v.valid, cfg, rng)
        obs.add(v.index, idx, rgb, rho2)
    return solve_exposure(obs, camera_of_image, cfg)


def set_exposure(views: list[SourceView], model: ExposureModel) -> None:
    for v in views:
        v.set_exposure(model)
