"""Source images at one reference exposure: the log's per-image gains and per-camera vignetting solved
from background seeds seen by several images (:mod:`nuav2.exposure`), set on the views before
anything reads their colours (seed colours, sky masks and texture, training targets). Pixels a
moving actor's box covers at that time are left out: the actor hides the seeds behind it."""

from __future__ import annotations

import numpy as np

from nuav2.exposure import (
    ExposureConfig,
    ExposureModel,
    Observations,
    sample_observations,
    solve_exposure,
    visible_points,
)
from nuav2.geometry import F64, T_inverse
from nuav2.splat.scene_model import TrackPoses
from nuav2.splat.views import SourceView
from nuav2.threads import ordered_thread_map
from nuav2.warp.depth_proxy import free_of_boxes


def free_pixels(view: SourceView, scene_T_city: F64, tracks: list[TrackPoses]) -> np.ndarray:
    """The view's valid pixels that no present track's box covers."""
    present = [t for t in tracks if t.present(view.timestamp_ns)]
    if not present:
        return view.valid
    scene_T_box = np.stack([t.scene_T_box_at(view.timestamp_ns) for t in present])
    size = np.stack([t.size_lwh for t in present])
    return view.valid & free_of_boxes(view.cam, scene_T_city @ view.city_T_cam, scene_T_box, size)


def solve_view_exposure(views: list[SourceView], points_scene: F64, scene_T_city: F64,
                        cfg: ExposureConfig | None = None, *, max_points: int = 30_000,
                        seed: int = 0, tracks: list[TrackPoses] = (), threads: int = 1) -> ExposureModel:
    """Exposure model over ``views`` (indexed by ``SourceView.index``, cameras by channel name order)
    from their raw colours at (a subsample of) static ``points_scene``, off the ``tracks``' boxes.
    ``threads``: images looked at in parallel (the result does not depend on it)."""
    cfg = cfg or ExposureConfig()
    rng = np.random.default_rng(seed)
    if len(points_scene) > max_points:
        points_scene = points_scene[np.sort(rng.choice(len(points_scene), max_points, replace=False))]
    channels = sorted({v.channel for v in views})
    n_img = max((v.index for v in views), default=-1) + 1
    camera_of_image = np.zeros(n_img, np.int64)
    obs = Observations()
    tracks = list(tracks)
    for track in tracks:
        track.prefetch([v.timestamp_ns for v in views])

    def seen_by(v: SourceView) -> tuple[SourceView, np.ndarray, F64, F64, np.ndarray]:
        """The points ``v`` sees, and its raw pixels: independent per view (worker threads)."""
        cam_T_scene = T_inverse(scene_T_city @ v.city_T_cam)
        image = v.raw_image_u8()
        idx, u, pv = visible_points(points_scene, v.cam.K, v.cam.width, v.cam.height, cam_T_scene,
                                    free_pixels(v, scene_T_city, tracks), cfg)
        return v, idx, u, pv, image

    for v, idx, u, pv, image in ordered_thread_map(seen_by, views, threads):  # in order: rng draws in order
        camera_of_image[v.index] = channels.index(v.channel)
        cam = v.cam
        obs.add(v.index, *sample_observations(idx, u, pv, image, cam.K, cam.width, cam.height, cfg, rng))
    return solve_exposure(obs, camera_of_image, cfg)


def set_exposure(views: list[SourceView], model: ExposureModel) -> None:
    for v in views:
        v.set_exposure(model)
