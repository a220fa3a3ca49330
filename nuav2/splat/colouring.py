"""Colouring seeds by projection: each seed takes the colour of the source image that sees it from
closest, behind a coarse z-buffer so a point hidden by a car does not take the car's colour."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from nuav2.geometry import F64, T_inverse
from nuav2.progress import progress_bar
from nuav2.splat.scene_model import TrackPoses
from nuav2.splat.sky_init import sky_mask
from nuav2.splat.views import Projection, SourceView, bilinear, project
from nuav2.threads import ordered_thread_map
from nuav2.zbuffer import nearest_surface

if TYPE_CHECKING:
    from nuav2.splat.init import InitConfig


def zbuffer_visible(proj: Projection, width: int, height: int, cfg: InitConfig,
                   valid: np.ndarray | None = None) -> np.ndarray:
    """Which projected points are the nearest surface in their (dilated) z-buffer cell, and (with
    ``valid``, an (H, W) bool mask) land on a valid pixel."""
    return nearest_surface(proj.u, proj.v, proj.z, width, height, cfg.zbuf_cell_px, cfg.zbuf_rel_tol,
                           cfg.zbuf_abs_tol_m, valid)


@dataclass
class SeedColours:
    """Per seed: RGB in [0,1] from its closest visible view (NaN if unseen), and the view count."""

    rgb: np.ndarray
    seen: np.ndarray
    sky_masks: dict[int, np.ndarray]  # view index -> (H, W) bool sky pixels


def colour_seeds(background: F64, objects: dict[str, F64], tracks: dict[str, TrackPoses],
                 views: list[SourceView], scene_T_city: F64, cfg: InitConfig, *,
                 progress: bool = False, threads: int = 1) -> tuple[SeedColours, dict[str, SeedColours]]:
    """Colour background (scene frame) and object (box frame) seeds from the views that see them.

    Objects are placed at each view's own timestamp. Also returns, per view, the sky mask:
    pixels looking above ``sky_min_elevation_deg`` with no seed projected within ``sky_dilate_px``.
    ``threads``: views projected at once (the result does not depend on it).
    """
    owners = ["background", *objects]
    sizes = [len(background), *(len(objects[t]) for t in objects)]
    offsets = np.concatenate([[0], np.cumsum(sizes)])
    n = int(offsets[-1])
    rgb = np.full((n, 3), np.nan, np.float32)
    best_z = np.full(n, np.inf)
    seen = np.zeros(n, np.int32)
    sky_masks: dict[int, np.ndarray] = {}
    min_sin = np.sin(np.radians(cfg.sky_min_elevation_deg))
    for tid in objects:
        tracks[tid].prefetch([v.timestamp_ns for v in views])

    def visible_in(view: SourceView) -> tuple[SourceView, Projection, np.ndarray]:
        """The seeds this view sees (nearest surface, valid pixel) and its sky mask; independent per
        view, so it runs on worker threads while the loop below merges views in order."""
        cam_T_scene = T_inverse(scene_T_city @ view.city_T_cam)
        parts = [project(background, view.cam, cam_T_scene)]  # the background as it is (no copy per view)
        for k, tid in enumerate(objects, start=1):
            tr = tracks[tid]
            if tr.present(view.timestamp_ns):
                part = project(objects[tid], view.cam, cam_T_scene @ tr.scene_T_box_at(view.timestamp_ns))
                parts.append(Projection(part.idx + offsets[k], part.u, part.v, part.z))
        proj = parts[0] if len(parts) == 1 else Projection(*(np.concatenate([getattr(q, f) for q in parts])
                                                               for f in ("idx", "u", "v", "z")))
        vis = zbuffer_visible(proj, view.cam.width, view.cam.height, cfg, view.valid)
        sky = sky_mask(view, scene_T_city, proj, min_sin, cfg.sky_dilate_px)
        view.image_u8()  # decoded here, off the merging thread
        return view, Projection(proj.idx[vis], proj.u[vis], proj.v[vis], proj.z[vis]), sky

    for view, hit, sky in progress_bar(ordered_thread_map(visible_in, views, threads), total=len(views),
                                       desc="colour seeds", unit="img", disable=not progress, leave=False):
        seen[hit.idx] += 1
        better = hit.z < best_z[hit.idx]
        if np.any(better):
            take = hit.idx[better]
            rgb[take] = bilinear(view.image(), hit.u[better], hit.v[better])
            best_z[take] = hit.z[better]
        sky_masks[view.index] = sky
    splits = [SeedColours(rgb[a:b], seen[a:b], sky_masks) for a, b in zip(offsets[:-1], offsets[1:])]
    return splits[0], dict(zip(owners[1:], splits[1:]))
