"""What no seed covers: sky masks (upward, uncovered, sky-coloured pixels), the sky texture's first
colours, and facade seeds for structure above the LiDAR's reach."""

from __future__ import annotations

from functools import lru_cache
from typing import TYPE_CHECKING

import cv2
import numpy as np

from nuav2.cells import unique_cells
from nuav2.geometry import F64, T_inverse
from nuav2.splat.sky import SKY_ELEV_MIN, SKY_INIT_RGB, camera_rays
from nuav2.splat.views import Projection, SourceView, project
from nuav2.threads import ordered_thread_map

if TYPE_CHECKING:
    from nuav2.splat.init import InitConfig


def sky_mask(view: SourceView, scene_T_city: F64, proj: Projection, min_sin: float,
              dilate: int) -> np.ndarray:
    h, w = view.cam.height, view.cam.width
    covered = np.zeros((h, w), np.uint8)
    rows = np.clip(np.round(proj.v).astype(np.int64), 0, h - 1)
    covered[rows, np.clip(np.round(proj.u).astype(np.int64), 0, w - 1)] = 1
    if dilate > 0:
        covered = cv2.dilate(covered, np.ones((2 * dilate + 1, 2 * dilate + 1), np.uint8))
    up = elevation_sin(view, scene_T_city) > min_sin
    return up & (covered == 0) & view.valid


def elevation_sin(view: SourceView, scene_T_city: F64) -> np.ndarray:
    """(H, W) sine of each pixel ray's elevation in the scene frame (z up)."""
    R = (scene_T_city @ view.city_T_cam)[:3, :3]
    K = view.cam.K
    unit_rays = _unit_rays_cam(float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]), view.cam.width,
                               view.cam.height)
    return unit_rays @ R[2]


@lru_cache(maxsize=32)
def _unit_rays_cam(fx: float, fy: float, cx: float, cy: float, width: int, height: int) -> np.ndarray:
    """(H, W, 3) unit camera-frame rays through the pixel centres, shared by every image of a camera:
    seeding asks for each image's elevations."""
    rays = camera_rays(fx, fy, cx, cy, width, height)
    d = rays / np.linalg.norm(rays, axis=-1, keepdims=True)
    d.flags.writeable = False
    return d


def refine_sky_masks(views: list[SourceView], candidates: dict[int, np.ndarray], scene_T_city: F64,
                     tol: float = 0.12, n_bins: int = 18, threads: int = 1) -> dict[int, np.ndarray]:
    """Keep only candidate sky pixels whose colour matches the sky at their elevation.

    LiDAR does not reach the tops of tall buildings, so "no seed projects here" also marks
    facades above the highest beam. The sky's colour per elevation band is the median over all
    candidates (facades are a minority), and a candidate stays sky only within ``tol`` (RGB
    distance in [0, 1]) of it. ``threads``: views looked at in parallel (same result)."""

    def samples(view: SourceView) -> tuple[int, np.ndarray, np.ndarray, np.ndarray] | None:
        """The view's elevation band per pixel (kept for the second pass; uint8, an eighth of the
        elevations' memory) and a subsample of its candidates' bands and colours."""
        m = candidates.get(view.index)
        if m is None or not m.any():
            return None
        e = elevation_sin(view, scene_T_city)
        band = np.clip((np.arcsin(np.clip(e, -1, 1)) / (np.pi / 2) * n_bins).astype(int), 0,
                       n_bins - 1).astype(np.uint8)
        idx = np.flatnonzero(m.ravel())[::7]  # a subsample is plenty for a median
        return view.index, band, band.ravel()[idx], view.image().reshape(-1, 3)[idx]

    picked = [x for x in ordered_thread_map(samples, views, threads) if x is not None]
    if not picked:
        return {k: v.copy() for k, v in candidates.items()}
    band_of = {index: band for index, band, _, _ in picked}
    bins = np.concatenate([b for _, _, b, _ in picked])
    sc = np.concatenate([c for _, _, _, c in picked])
    ref = np.full((n_bins, 3), np.nan)
    for b in range(n_bins):
        if np.any(bins == b):
            ref[b] = np.median(sc[bins == b], axis=0)
    ok = np.all(np.isfinite(ref), axis=1)
    if not ok.any():
        return {k: v.copy() for k, v in candidates.items()}
    good = np.flatnonzero(ok)
    ref = ref[good[np.argmin(np.abs(good[None, :] - np.arange(n_bins)[:, None]), axis=1)]]  # fill gaps

    def refined(view: SourceView) -> np.ndarray:
        m = candidates.get(view.index)
        if m is None:
            return np.zeros((view.cam.height, view.cam.width), bool)
        if not m.any():
            return m.copy()
        return m & (np.linalg.norm(view.image() - ref[band_of[view.index]], axis=-1) < tol)

    return {view.index: mask for view, mask in zip(views, ordered_thread_map(refined, views, threads))}


def facade_seeds(views: list[SourceView], candidates: dict[int, np.ndarray], sky: dict[int, np.ndarray],
                 lidar_scene: F64, scene_T_city: F64, cfg: InitConfig) -> tuple[F64, np.ndarray]:
    """Seeds for structure above the LiDAR's reach (tall facades), with their pixel colours.

    Pixels that no seed covers but that are not sky either are placed along their ray at the
    camera depth of the nearest LiDAR-covered pixel below them in the same column: on a vertical
    facade seen by a level camera that depth is constant up the column."""
    pts_out, rgb_out = [], []
    max_gap = cfg.facade_max_gap_frac
    for view in views[:: max(1, cfg.facade_view_stride)]:
        cand, sk = candidates.get(view.index), sky.get(view.index)
        if cand is None or sk is None:
            continue
        miss = cand & ~sk
        if not miss.any():
            continue
        h, w = view.cam.height, view.cam.width
        scene_T_cam = scene_T_city @ view.city_T_cam
        proj = project(lidar_scene, view.cam, T_inverse(scene_T_cam))
        zimg = np.full(h * w, np.inf)
        rows = np.clip(np.round(proj.v).astype(np.int64), 0, h - 1)
        np.minimum.at(zimg, rows * w + np.clip(np.round(proj.u).astype(np.int64), 0, w - 1), proj.z)
        zimg = zimg.reshape(h, w)
        carried = zimg.copy()
        age = np.where(np.isfinite(zimg), 0, h)
        for r in range(h - 2, -1, -1):  # carry the depth upwards, remembering how far it came
            take = ~np.isfinite(zimg[r]) & np.isfinite(carried[r + 1])
            carried[r] = np.where(take, carried[r + 1], zimg[r])
            age[r] = np.where(take, age[r + 1] + 1, age[r])
        pick = miss & np.isfinite(carried) & (age <= max_gap * h)
        pick[1::2] = False
        pick[:, 1::2] = False
        vv, uu = np.nonzero(pick)
        if len(vv) == 0:
            continue
        K = view.cam.K
        z = carried[vv, uu]
        p_cam = np.column_stack([(uu - K[0, 2]) / K[0, 0] * z, (vv - K[1, 2]) / K[1, 1] * z, z])
        pts_out.append(p_cam @ scene_T_cam[:3, :3].T + scene_T_cam[:3, 3])
        rgb_out.append(view.image()[vv, uu])
    if not pts_out:
        return np.zeros((0, 3)), np.zeros((0, 3), np.float32)
    pts, rgb = np.concatenate(pts_out), np.concatenate(rgb_out)
    # One seed per voxel (the first pixel's colour), so many views of a facade do not pile up.
    first = np.sort(unique_cells(pts, 2 * cfg.voxel_m)[0])
    return pts[first], rgb[first]


def sky_row_elevations(height: int) -> np.ndarray:
    """Elevation (radians) of each row centre of a ``height``-row sky texture (row 0: the zenith)."""
    return np.pi / 2 - np.arange(height) / max(height - 1, 1) * (np.pi / 2 - SKY_ELEV_MIN)


def sky_texture_from_views(views: list[SourceView], sky_masks: dict[int, np.ndarray], scene_T_city: F64,
                           height: int, width: int, threads: int = 1,
                           below_horizon_rgb: np.ndarray | None = None) -> np.ndarray | None:
    """(H, W, 3) mean sky colour per lat-long bin from the sky pixels, holes filled by row means
    (then the nearest row on the same side of the horizon, then the overall mean, or the sky model's
    default colour where no view has a sky pixel); None if no view has a sky pixel and no
    ``below_horizon_rgb`` is given. ``threads``: views binned in parallel.

    ``below_horizon_rgb`` (the road's colour): fills the bins below the horizon that no sky pixel
    reached. The sky is drawn behind every pixel the Gaussians leave partly transparent, and below
    the horizon that is road: filled with the horizon's sky colour instead, a see-through patch of
    road behind the ego showed pale blue in a target camera looking back."""
    import torch

    from nuav2.splat.scene_model import SkyModel, pixel_rays

    acc = np.zeros((height * width, 3))
    cnt = np.zeros(height * width)
    n_bins = height * width

    def binned(view: SourceView) -> tuple[np.ndarray, np.ndarray] | None:
        """Texture bin and colour of every other sky pixel of a view (worker threads)."""
        m = sky_masks.get(view.index)
        if m is None or not m.any():
            return None
        m = m.copy()
        m[1::2] = False  # every other row and column is plenty for a 32 x 128 texture
        m[:, 1::2] = False
        dirs = pixel_rays(view.cam, scene_T_city @ view.city_T_cam)[torch.from_numpy(m)]
        g = SkyModel.direction_to_grid(dirs, width).numpy()
        col = np.clip(np.round((g[:, 0] + 1) / 2 * width).astype(np.int64), 0, width) % width
        row = np.clip(np.round((g[:, 1] + 1) / 2 * (height - 1)).astype(np.int64), 0, height - 1)
        return row * width + col, view.image()[m]

    for got in ordered_thread_map(binned, views, threads):  # summed in view order: the same bytes
        if got is None:
            continue
        bins, pix = got
        for c in range(3):
            acc[:, c] += np.bincount(bins, weights=pix[:, c], minlength=n_bins)
        cnt += np.bincount(bins, minlength=n_bins)
    if cnt.sum() == 0 and below_horizon_rgb is None:
        return None
    overall = acc.sum(0) / cnt.sum() if cnt.sum() else np.asarray(SKY_INIT_RGB, np.float64)
    tex = np.where(cnt[:, None] > 0, acc / np.maximum(cnt, 1)[:, None], np.nan).reshape(height, width, 3)
    # Rows take a missing row's colour from their own side of the horizon: sky from sky, road from road.
    side = np.zeros(height, bool)
    if below_horizon_rgb is not None:
        side = sky_row_elevations(height) < 0
        tex[side] = np.where(np.isfinite(tex[side]), tex[side], np.asarray(below_horizon_rgb, np.float64))
    for r in range(height):
        row = tex[r]
        ok = np.all(np.isfinite(row), axis=1)
        row[~ok] = row[ok].mean(0) if ok.any() else np.nan
    rows_ok = np.all(np.isfinite(tex[:, 0]), axis=1)
    for r in range(height):
        if not rows_ok[r]:
            donors = np.flatnonzero(rows_ok & (side == side[r]))
            tex[r] = tex[donors[np.argmin(np.abs(donors - r))]] if len(donors) else overall
    return tex
