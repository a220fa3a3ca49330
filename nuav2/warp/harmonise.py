"""Warp mode's source images at one reference exposure: gains solved on their overlaps before blending.

Source images are read at a reduced size (about ``work_width_px`` wide) and look at static points:
the ground surface on a grid along the ego path and the static LiDAR of every few sweeps
(voxel-downsampled), on the pixels no labelled actor covers at that time (a passing truck hides the
static points behind it, and its colour would tie the image's exposure to the truck's paint). Points
seen by several images tie their exposures together (:mod:`nuav2.exposure`). Only ``observe_hz``
images per camera and second are read; the others' gains are interpolated in time (auto-exposure
moves smoothly over a few frames). The solved per-image gains and per-camera vignetting then divide
each source image as it is loaded, so blended seams and consecutive target images agree.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from nuav2.cells import unique_cells
from nuav2.exposure import (
    ExposureConfig,
    ExposureModel,
    Observations,
    frames_to_observe,
    interpolate_log_gains,
    local_points,
    observe,
    solve_exposure,
)
from nuav2.geometry import F64, T_inverse, translation_T
from nuav2.image_decode import load_image_u8
from nuav2.rig import EGO_COLOUR_MARGIN_PX, CameraSpec
from nuav2.scene import CameraFrame, SceneLog
from nuav2.warp.depth_proxy import free_of_boxes
from nuav2.warp.tracks import BoxesAt

WORK_WIDTH_PX = 320
GROUND_SPACING_M = 0.5
GROUND_RADIUS_M = 20.0
LIDAR_VOXEL_M = 0.3
SWEEP_STRIDE = 5


def read_reduced(path: Path, camera: CameraSpec,
                 width_px: int = WORK_WIDTH_PX) -> tuple[np.ndarray, CameraSpec]:
    """uint8 RGB image at about ``width_px`` wide (decoded reduced where that is exact) and its camera."""
    scale = min(1.0, width_px / camera.width)
    small = camera.scaled(scale) if scale < 1.0 else camera
    return load_image_u8(path, small.width, small.height, (camera.width, camera.height)), small


def static_points(scene: SceneLog, sweep_points: Callable[[int], F64]) -> F64:
    """City points for the solve: a ground grid along the path (the log's ground-height raster, else the
    height under the nearest ego pose) and the static LiDAR of every few sweeps, voxel-downsampled."""
    from scipy.spatial import cKDTree

    path = scene.city_T_ego[:, :2, 3]
    lo, hi = path.min(0) - GROUND_RADIUS_M, path.max(0) + GROUND_RADIUS_M
    gx, gy = np.meshgrid(np.arange(lo[0], hi[0], GROUND_SPACING_M), np.arange(lo[1], hi[1], GROUND_SPACING_M))
    xy = np.column_stack([gx.ravel(), gy.ravel()])
    dist, nearest = cKDTree(path).query(xy, k=1)
    near = np.asarray(dist) <= GROUND_RADIUS_M
    xy, nearest = xy[near], np.asarray(nearest)[near]
    z = scene.city_T_ego[nearest, 2, 3] - scene.rig.origin_height_m
    if scene.ground_height is not None:
        zr = scene.ground_height.height_at(xy)
        z = np.where(np.isfinite(zr), zr, z)
    parts = [np.column_stack([xy, z])]
    if scene.load_lidar is not None:
        parts += [sweep_points(i) for i in range(0, len(scene.lidar_sweeps), SWEEP_STRIDE)]
    pts = np.concatenate(parts)
    first, _, _ = unique_cells(pts, LIDAR_VOXEL_M)
    return pts[np.sort(first)]


def solve_source_exposure(scene: SceneLog, frames: dict[str, list[CameraFrame]], points_city: F64,
                          cfg: ExposureConfig, boxes_at: Callable[[int], BoxesAt] | None = None
                          ) -> tuple[ExposureModel, dict[tuple[str, int], int]]:
    """Exposure model over every source image and the image index of each (channel, frame index);
    ``boxes_at(timestamp_ns)``: the labelled actors, whose pixels are left out."""
    channels = list(frames)
    index: dict[tuple[str, int], int] = {}
    cams: list[int] = []
    stamps: list[int] = []
    observed: list[int] = []
    obs = Observations()
    rng = np.random.default_rng(0)
    points_local, centre = local_points(points_city)
    city_T_local = translation_T(*centre)
    for c, ch in enumerate(channels):
        cam = scene.rig.camera(ch)
        start = len(cams)
        for j, f in enumerate(frames[ch]):
            index[(ch, j)] = len(cams)
            cams.append(c)
            stamps.append(int(f.timestamp_ns))
        chosen = frames_to_observe(np.array(stamps[start:], np.int64), cfg.observe_hz,
                                   cfg.min_observed_per_camera)
        for j in chosen:
            f = frames[ch][int(j)]
            img, small = read_reduced(Path(f.path), cam)
            city_T_cam = scene.city_T_ego_at(int(f.timestamp_ns)) @ cam.ego_T_cam
            valid = ~small.ego_mask(EGO_COLOUR_MARGIN_PX) if small.ego_mask_polygons else None
            boxes = boxes_at(int(f.timestamp_ns)) if boxes_at is not None else None
            if boxes is not None and len(boxes):
                free = free_of_boxes(small, city_T_cam, boxes.city_T_box, boxes.size_lwh)
                valid = free if valid is None else valid & free
            idx, rgb, rho2 = observe(points_local, small.K, small.width, small.height,
                                     T_inverse(city_T_cam) @ city_T_local,
                                     img, valid, cfg, rng)
            obs.add(len(observed), idx, rgb, rho2)
            observed.append(start + int(j))
    cam_arr = np.array(cams, np.int64)
    chosen_model = solve_exposure(obs, cam_arr[observed], cfg)
    return interpolate_log_gains(chosen_model, np.array(observed, np.int64), np.array(stamps, np.int64),
                                 cam_arr), index
