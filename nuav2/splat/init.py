"""Seeding a scene from the log: which tracks move, LiDAR aggregation, ground seeds, colours.

Street Gaussians initialises from LiDAR instead of structure-from-motion: every sweep is moved
into the scene frame; points inside a *moving* track's box go to that track (in its box frame),
everything else (static tracks included) is background, voxel-downsampled more coarsely far
from the ego path. Ground seeds on the ground-height surface fill the gaps between LiDAR rings
where lane paint lives. Every seed is coloured from the source image that sees it closest,
behind a coarse z-buffer so a point hidden by a car does not take the car's colour; seeds that
no camera sees are dropped. The same projection marks, per training view, which upward pixels
no seed covers: the sky mask the sky model and the opacity loss train on.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from nuav2.exposure import ExposureConfig, ExposureModel
from nuav2.geometry import F64, T_inverse
from nuav2.scene import SceneLog
from nuav2.splat.actors import build_tracks, object_tracks
from nuav2.splat.budget import (
    TIER_FAR,
    TIER_GROUND,
    TIER_NAMES,
    TIER_NEAR,
    TIER_PAINT,
    BudgetConfig,
    GroundSeeds,
    keep_by_priority,
    merge_plain_ground,
    merge_plain_structure,
    scene_budget,
)
from nuav2.splat.colouring import colour_seeds
from nuav2.splat.ground import GroundSurface, fill_unseen_ground, ground_seeds, occupied_cells
from nuav2.splat.harmonise import set_exposure, solve_view_exposure
from nuav2.splat.lidar_seeds import (
    aggregate_lidar,
    banded_downsample,
    box_surface_points,
    cap_points,
    distance_bands,
    knn_scales,
    voxel_downsample,
)
from nuav2.splat.sky_init import facade_seeds, refine_sky_masks, sky_texture_from_views
from nuav2.splat.views import SourceView, load_image, source_views

# Re-exported for callers that build views and seeds through this one module.
__all__ = ["InitConfig", "InitResult", "SourceView", "initial_scene", "load_image", "source_views"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class InitConfig:
    """Knobs of the LiDAR seeding (metres unless named otherwise)."""

    sweep_stride: int = 1  # aggregate every k-th sweep
    voxel_m: float = 0.15  # background voxel near the path; x2 per distance band
    voxel_bands_m: tuple[float, ...] = (20.0, 40.0, 80.0)  # distance-to-path band edges
    object_voxel_m: float = 0.08
    max_background: int = 150_000
    max_object_points: int = 5_000
    min_object_points: int = 300  # fewer LiDAR points: fill with random points on the box surface
    box_margin_m: float = 0.25  # in-box test margin (points on the box skin belong to the object)
    max_range_m: float = 150.0
    ego_box_min: tuple[float, float, float] = (-1.3, -1.2, -0.6)  # ego-frame box of the ego body
    ego_box_max: tuple[float, float, float] = (4.2, 1.2, 1.6)
    ground_spacing_m: float = 0.25  # 0 disables ground seeds
    ground_radius_m: float = 30.0  # ground seeds within this distance of the ego path
    ground_clear_height_m: float = 0.3  # a ground cell with LiDAR higher than this is occupied
    opacity: float = 0.3
    min_scale_m: float = 0.02
    max_scale_m: float = 2.0
    zbuf_cell_px: int = 2  # z-buffer cell at training resolution
    zbuf_rel_tol: float = 0.05
    zbuf_abs_tol_m: float = 0.3
    keep_unseen: bool = False
    # Ground no source image saw (behind a waiting ego, under its body) within this distance of seen ground
    # is kept with its seen neighbours' median colour, opaque (training never reaches it); 0: dropped.
    unseen_ground_reach_m: float = 12.0
    unseen_ground_neighbours: int = 16
    unseen_ground_opacity: float = 0.95
    sky_height: int = 32
    sky_width: int = 128
    sky_min_elevation_deg: float = 1.0
    sky_dilate_px: int = 3
    sky_colour_tol: float = 0.12  # a sky candidate must be this close (RGB, [0,1]) to the sky's colour
    facade_view_stride: int = 4  # facade seeds from every k-th view (0 disables them)
    facade_max_gap_frac: float = 0.4  # carry LiDAR depth up a column at most this fraction of the height
    motion_min_path_m: float = 1.0  # a track moves if its path is longer than this ...
    motion_min_std_m: float = 0.3  # ... and its position spread (largest axis std) exceeds this
    motion_min_observations: int = 2
    smooth_tracks: bool = True  # take per-frame label jitter out of the box tracks (nuav2.actor_tracks)
    nonrigid_segment_s: float = 0.2  # moving pedestrians/cyclists: one object per segment (0: rigid)
    exposure: ExposureConfig | None = field(default_factory=ExposureConfig)  # None: images used as taken
    exposure_points: int = 30_000  # background seeds the exposure solve looks at
    budget: BudgetConfig | None = field(default_factory=BudgetConfig)  # None: fixed budget, uniform thinning


# ---- the initial scene -----------------------------------------------------------------------------

LIDAR, GROUND, FACADE = 0, 1, 2  # kinds of background seeds


@dataclass
class InitResult:
    """The seeded scene plus what training needs from seeding (sky masks) and a summary."""

    scene: object  # SplatScene (typed loosely to keep the import light)
    sky_masks: dict[int, np.ndarray]
    stats: dict
    exposure: ExposureModel | None = None
    budget: int | None = None  # densification budget for this scene (None: the training config's)


def _unseen_ground(xyz: F64, rgb: np.ndarray, kept: np.ndarray, cell: np.ndarray,
                   cfg: InitConfig) -> GroundSeeds:
    """The ground seeds not kept (no image saw them) that :func:`fill_unseen_ground` colours from the kept
    ones, as fine seeds."""
    idx, colours = fill_unseen_ground(xyz, rgb, kept, cfg.unseen_ground_reach_m, cfg.unseen_ground_neighbours)
    return GroundSeeds(xyz[idx], colours, cell[idx], np.ones(len(idx), np.int64))


def _merge_structure(points: F64, rgb: np.ndarray, path_xy: F64, cfg: InitConfig) -> tuple[F64, np.ndarray]:
    """:func:`merge_plain_structure` on the voxel bands the LiDAR was downsampled on."""
    band = distance_bands(points[:, :2], path_xy, cfg.voxel_bands_m)
    levels, tol = cfg.budget.structure_merge_levels, cfg.budget.merge_tol
    merged, merged_rgb, _ = merge_plain_structure(points, rgb, band, cfg.voxel_m, levels, tol)
    return merged, merged_rgb


def initial_scene(scene: SceneLog, views: list[SourceView], cfg: InitConfig, *, sh_degree: int = 1,
                  seed: int = 0, progress: bool = False, other_views: list[SourceView] = (),
                  threads: int = 1) -> InitResult:
    """Seed background, moving objects and sky from the log's LiDAR, ground surface and images.

    With ``cfg.exposure`` the views (and ``other_views``, e.g. held-out images) are first brought to
    the log's reference exposure (:mod:`nuav2.splat.harmonise`). ``threads``: per-image work in parallel
    (the result does not depend on it)."""
    import torch

    from nuav2.splat.scene_model import GaussianSet, ObjectModel, SkyModel, SplatScene, scene_frame_for
    from nuav2.splat.sky import inverse_sigmoid

    rng = np.random.default_rng(seed)
    city_T_scene = scene_frame_for(scene.city_T_ego[0])
    scene_T_city = T_inverse(city_T_scene)
    tracks = build_tracks(scene, scene_T_city, smooth=cfg.smooth_tracks)
    moving = {t.key: t for t in object_tracks(tracks, cfg)}
    agg = aggregate_lidar(scene, scene_T_city, moving, cfg, progress=progress)
    path_xy = (scene_T_city[None] @ scene.city_T_ego)[:, :2, 3]
    bg_lidar = banded_downsample(agg.background, path_xy, cfg.voxel_m, cfg.voxel_bands_m)

    surface = GroundSurface(scene, scene_T_city, bg_lidar)
    occupied = occupied_cells(bg_lidar, surface, cfg.ground_clear_height_m)
    ground, ground_cell = ground_seeds(surface, occupied, cfg)
    bg_pts = np.concatenate([bg_lidar, ground])
    kind = np.concatenate([np.full(len(bg_lidar), LIDAR), np.full(len(ground), GROUND)])
    exposure = None
    if cfg.exposure is not None:
        every = [*views, *other_views]
        exposure = solve_view_exposure(every, bg_pts, scene_T_city, cfg.exposure,
                                       max_points=cfg.exposure_points, seed=seed,
                                       tracks=list(moving.values()), threads=threads)
        set_exposure(every, exposure)
    obj_pts: dict[str, F64] = {}
    for tid, pts in agg.objects.items():
        pts = cap_points(voxel_downsample(pts, cfg.object_voxel_m), cfg.max_object_points, rng)
        if len(pts) < cfg.min_object_points:
            extra = box_surface_points(moving[tid].size_lwh, cfg.min_object_points - len(pts), rng)
            pts = np.concatenate([pts, extra])
        obj_pts[tid] = pts
    bg_col, obj_col = colour_seeds(bg_pts, obj_pts, moving, views, scene_T_city, cfg, progress=progress,
                                    threads=threads)

    sky_masks = refine_sky_masks(views, bg_col.sky_masks, scene_T_city, cfg.sky_colour_tol, threads=threads)

    keep = np.isfinite(bg_col.rgb).all(1) if not cfg.keep_unseen else np.ones(len(bg_pts), bool)
    bg_rgb = np.where(np.isfinite(bg_col.rgb), bg_col.rgb, 0.5)
    is_ground = kind == GROUND
    # Plain ground merges into coarser discs; textured ground (paint) keeps its fine seeds.
    g = GroundSeeds(bg_pts[is_ground & keep], bg_rgb[is_ground & keep], ground_cell[keep[is_ground]],
                    np.ones(int((is_ground & keep).sum()), np.int64))
    n_fine = len(g)
    g_fill = _unseen_ground(bg_pts[is_ground], bg_rgb[is_ground], keep[is_ground], ground_cell, cfg)
    if cfg.budget is not None:
        g = merge_plain_ground(g, cfg.budget.merge_levels, cfg.budget.merge_tol)
        g_fill = merge_plain_ground(g_fill, cfg.budget.merge_levels, cfg.budget.merge_tol)
    rest = ~is_ground & keep
    facade, facade_rgb = (facade_seeds(views, bg_col.sky_masks, sky_masks, bg_lidar, scene_T_city, cfg)
                          if cfg.facade_view_stride > 0 else (np.zeros((0, 3)), np.zeros((0, 3))))
    lidar, lidar_rgb = bg_pts[rest], bg_rgb[rest]
    n_structure_fine = len(lidar) + len(facade)
    if cfg.budget is not None and cfg.budget.structure_merge_levels > 0:
        # Plain walls and parked cars merge into coarser seeds; window frames, signs and trunks keep theirs.
        lidar, lidar_rgb = _merge_structure(lidar, lidar_rgb, path_xy, cfg)
        facade, facade_rgb = _merge_structure(facade, facade_rgb, path_xy, cfg)
    bg_pts = np.concatenate([g.xyz, g_fill.xyz, lidar, facade])
    bg_rgb = np.concatenate([g.rgb, g_fill.rgb, lidar_rgb, facade_rgb])
    n_rest = len(lidar) + len(facade)
    kind = np.concatenate([np.full(len(g) + len(g_fill), GROUND), np.full(len(lidar), LIDAR),
                           np.full(len(facade), FACADE)])
    filled = np.concatenate([np.zeros(len(g), bool), np.ones(len(g_fill), bool), np.zeros(n_rest, bool)])
    spacing = np.concatenate([g.size * cfg.ground_spacing_m, g_fill.size * cfg.ground_spacing_m,
                              np.zeros(n_rest)])
    tier = np.where(kind == GROUND, np.where((spacing <= cfg.ground_spacing_m) & ~filled, TIER_PAINT,
                                             TIER_GROUND),
                    np.where(distance_bands(bg_pts[:, :2], path_xy, cfg.voxel_bands_m[:1]) == 0, TIER_NEAR,
                             TIER_FAR))
    if cfg.budget is None:  # the former rule: a uniform sample over all seeds
        tier = np.zeros(len(tier), np.int64)
    # Structure near and far is thinned alike: far seeds are already sparse (coarser voxel bands), and
    # dropping them first blanked the far side of a wide road (-5 dB on the arterial's left cameras).
    sel = keep_by_priority(np.minimum(tier, TIER_NEAR), cfg.max_background, rng)
    bg_pts, bg_rgb, kind, spacing, tier = bg_pts[sel], bg_rgb[sel], kind[sel], spacing[sel], tier[sel]
    filled = filled[sel]
    is_ground = kind == GROUND
    scales = np.repeat(knn_scales(bg_pts, 3, cfg.min_scale_m, cfg.max_scale_m)[:, None], 3, axis=1)
    # Ground seeds are flat discs on a regular grid: they tile the road without gaps or bumps.
    scales[is_ground, 0] = scales[is_ground, 1] = 0.6 * spacing[is_ground]
    scales[is_ground, 2] = 0.02
    background = GaussianSet.create(bg_pts, bg_rgb, scales, opacity=cfg.opacity, sh_degree=sh_degree)
    if filled.any():  # nothing trains them: they must cover the road as they are
        opaque = float(inverse_sigmoid(cfg.unseen_ground_opacity))
        background.opacity_logits[torch.from_numpy(filled)] = opaque

    objects = []
    for tid, pts in obj_pts.items():
        col = obj_col[tid]
        ok = np.isfinite(col.rgb).all(1)
        if not ok.any():
            log.info("track %s: no camera sees it; not modelled", tid)
            continue
        fill = np.nanmean(col.rgb[ok], axis=0)
        rgb = np.where(ok[:, None], col.rgb, fill)
        sc = knn_scales(pts, 3, cfg.min_scale_m, 0.5)
        objects.append(ObjectModel(moving[tid], GaussianSet.create(pts, rgb, sc, opacity=cfg.opacity,
                                                                   sh_degree=sh_degree)))

    sky = SkyModel(cfg.sky_height, cfg.sky_width)
    road_rgb = np.median(g.rgb, axis=0) if len(g) else None  # seen ground: what lies below the horizon
    tex = sky_texture_from_views(views, sky_masks, scene_T_city, cfg.sky_height, cfg.sky_width,
                                 threads=threads, below_horizon_rgb=road_rgb)
    if tex is not None:
        with torch.no_grad():
            p = torch.from_numpy(np.clip(tex, 0.02, 0.98)).float().permute(2, 0, 1)
            sky.texture.copy_(torch.log(p / (1 - p)))
    splat = SplatScene(city_T_scene, background, objects, sky)
    n_seeds = len(background) + sum(len(o.gaussians) for o in objects)
    n_moving = len({o.track.track_id for o in objects})
    budget = scene_budget(n_seeds, n_moving, cfg.budget) if cfg.budget is not None else None
    stats = {"tracks": len(tracks), "moving_tracks": len({t.track_id for t in moving.values()}),
             "objects": len(objects),
             "non_rigid_segments": sum(t.segment is not None for t in moving.values()),
             "lidar_sweeps": agg.n_sweeps, "lidar_points": agg.n_points,
             "background_lidar_seeds": int((kind == LIDAR).sum()),
             "facade_seeds": int((kind == FACADE).sum()), "structure_seeds_fine": n_structure_fine,
             "ground_seeds": int(is_ground.sum()), "ground_seeds_fine": n_fine,
             "unseen_ground_seeds": int(filled.sum()),
             "seeds_by_tier": {name: int((tier == t).sum()) for t, name in enumerate(TIER_NAMES)},
             "gaussian_budget": budget,
             "background_gaussians": len(background),
             "object_gaussians": int(sum(len(o.gaussians) for o in objects)),
             "sky_pixels": int(sum(int(m.sum()) for m in sky_masks.values()))}
    return InitResult(splat, sky_masks, stats, exposure, budget)
