"""The Gaussian budget follows the scene: plain ground merges into coarse discs, paint keeps fine seeds,
thinning keeps ground and paint first, and the densification budget grows with seeds and moving tracks."""

from __future__ import annotations

import numpy as np

from nuav2.splat.budget import (
    TIER_FAR,
    TIER_GROUND,
    TIER_NEAR,
    TIER_PAINT,
    BudgetConfig,
    GroundSeeds,
    keep_by_priority,
    merge_plain_ground,
    merge_plain_structure,
    scene_budget,
)


def grid_seeds(n: int, spacing: float, colour_fn) -> GroundSeeds:
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    cell = np.column_stack([i.ravel(), j.ravel()])
    xy = (cell + 0.5) * spacing
    rgb = np.array([colour_fn(x, y) for x, y in xy], np.float64)
    return GroundSeeds(np.column_stack([xy, np.zeros(len(xy))]), rgb, cell, np.ones(len(xy), np.int64))


def test_plain_ground_merges_and_paint_keeps_its_fine_seeds():
    # 16 x 16 cells of 0.25 m: dark asphalt with a 0.25 m wide white line along x = 2.0 .. 2.25 m.
    paint = lambda x, y: (0.9, 0.9, 0.9) if 2.0 <= x < 2.25 else (0.3, 0.3, 0.32)  # noqa: E731
    seeds = grid_seeds(16, 0.25, paint)
    merged = merge_plain_ground(seeds, levels=2, tol=0.05)
    assert len(merged) < len(seeds) / 2
    # the line's cells are still there at full resolution, with their colour
    line = merged.size == 1
    assert np.all(merged.rgb[line][:, 0] > 0.8) or np.all(merged.xyz[line][:, 0] >= 1.75)
    fine_white = (merged.size == 1) & (merged.rgb[:, 0] > 0.8)
    assert fine_white.sum() == 16  # every paint seed of the 16 rows kept
    # merged discs are 2 or 4 cells wide and keep the asphalt colour; the area is conserved
    assert set(np.unique(merged.size)) <= {1, 2, 4} and np.all(merged.rgb[merged.size > 1][:, 0] < 0.35)
    assert (merged.size ** 2).sum() == len(seeds)
    # a fully plain patch collapses 16:1
    plain = merge_plain_ground(grid_seeds(8, 0.25, lambda x, y: (0.3, 0.3, 0.3)), levels=2, tol=0.05)
    assert len(plain) == 4 and np.all(plain.size == 4)
    np.testing.assert_allclose(np.sort(plain.xyz[:, 0]), [0.5, 0.5, 1.5, 1.5])  # block centres


def test_plain_structure_merges_and_textured_structure_keeps_its_seeds():
    # Two 3 x 3 m walls of 0.15 m LiDAR voxels: one plain, one with a 0.15 m checker (texture finer than the
    # merge voxel), and a far plain wall in distance band 1 (voxels twice the size).
    g = (np.arange(20) + 0.5) * 0.15
    yy, zz = (a.ravel() for a in np.meshgrid(g, g))
    plain = np.column_stack([np.full(400, 5.05), yy, zz])
    checker = plain + [0.0, 6.0, 0.0]
    far = np.column_stack([np.full(100, 40.1), (np.arange(100) % 10 + 0.5) * 0.3,
                           (np.arange(100) // 10 + 0.5) * 0.3])
    dark = ((np.floor(checker[:, 1] / 0.15) + np.floor(checker[:, 2] / 0.15)) % 2).astype(bool)
    rgb = np.concatenate([np.full((400, 3), 0.4), np.where(dark[:, None], 0.1, 0.9) * np.ones(3),
                          np.full((100, 3), 0.6)])
    band = np.concatenate([np.zeros(800, np.int64), np.ones(100, np.int64)])
    pts, col, size = merge_plain_structure(np.concatenate([plain, checker, far]), rgb, band, 0.15, 2, 0.05)
    near = pts[:, 0] < 10
    is_plain, is_checker = near & (pts[:, 1] < 3.5), near & (pts[:, 1] > 5.5)
    assert is_checker.sum() == 400 and np.all(size[is_checker] == 1)  # every textured seed kept
    # each plain voxel of 4 x 4 seeds (0.6 m) ends as one seed of four times the spacing, its mean colour
    assert is_plain.sum() == 25 and np.all(size[is_plain] == 4)
    np.testing.assert_allclose(col[is_plain], 0.4)
    np.testing.assert_allclose(np.sort(pts[is_plain, 1])[::5], (np.arange(5) + 0.5) * 0.6, atol=1e-9)
    far_left = ~is_plain & ~is_checker  # band 1 merges on 0.6 m, then 1.2 m voxels
    assert far_left.sum() == 9 and np.isclose(pts[far_left, 0], 40.1).all()
    # nothing merges at levels=0 or with a tolerance below the colours' spread
    assert len(merge_plain_structure(plain, rgb[:400], band[:400], 0.15, 0, 0.05)[0]) == 400
    jitter = rgb[:400] + np.random.default_rng(0).uniform(-0.1, 0.1, (400, 3))
    assert len(merge_plain_structure(plain, jitter, band[:400], 0.15, 2, 0.01)[0]) == 400


def test_thinning_keeps_tiers_in_order_and_samples_the_straddling_one():
    rng = np.random.default_rng(0)
    tier = np.array([TIER_FAR] * 50 + [TIER_PAINT] * 10 + [TIER_NEAR] * 30 + [TIER_GROUND] * 20)
    keep = keep_by_priority(tier, 45, rng)
    assert len(keep) == 45 and np.all(np.diff(keep) > 0)
    kept = tier[keep]
    assert (kept == TIER_PAINT).sum() == 10 and (kept == TIER_GROUND).sum() == 20
    assert (kept == TIER_NEAR).sum() == 15 and (kept == TIER_FAR).sum() == 0
    assert len(keep_by_priority(tier, 1000, rng)) == len(tier)


def test_budget_grows_with_seeds_and_moving_tracks_within_bounds():
    cfg = BudgetConfig(growth=1.25, per_moving_track=1500, min_budget=20_000, max_budget=150_000)
    assert scene_budget(40_000, 0, cfg) == 50_000
    assert scene_budget(40_000, 4, cfg) == 56_000
    assert scene_budget(1_000, 0, cfg) == 20_000 and scene_budget(10**6, 0, cfg) == 150_000


def test_seeding_a_log_gives_a_scene_budget_and_coarse_plain_ground(tmp_path):
    from converters.av2 import read_log
    from nuav2.splat.init import InitConfig, initial_scene, source_views
    from nuav2.synth import SynthConfig, generate_log

    small = SynthConfig(seconds=0.3, image_scale=1 / 16, lidar_azimuth_steps=256, n_parked=1, n_moving=1,
                        n_pedestrians=0, map_margin_m=25.0)
    log = generate_log(tmp_path, seed=2, config=small)
    scene = read_log(log)
    views = source_views(scene, 1.0)
    cfg = InitConfig(max_background=20_000, ground_spacing_m=0.25, ground_radius_m=12.0, exposure=None)
    res = initial_scene(scene, views, cfg, sh_degree=0)
    st = res.stats
    seen_ground = st["ground_seeds"] - st["unseen_ground_seeds"]
    assert seen_ground < 0.6 * st["ground_seeds_fine"]  # plain asphalt and sidewalk merged
    structure = st["background_lidar_seeds"] + st["facade_seeds"]
    assert structure < 0.8 * st["structure_seeds_fine"]  # plain walls merged too
    assert st["seeds_by_tier"]["textured ground"] > 200  # paint, kerbs and crossings stayed fine
    n_seeds = st["background_gaussians"] + st["object_gaussians"]
    assert res.budget == scene_budget(n_seeds, st["moving_tracks"], cfg.budget)
    from dataclasses import replace

    fixed = initial_scene(scene, views, replace(cfg, budget=None), sh_degree=0)
    assert fixed.budget is None  # no merging: every fine seed, seen or filled, is its own Gaussian
    fs = fixed.stats
    assert fs["ground_seeds"] == fs["ground_seeds_fine"] + fs["unseen_ground_seeds"]
    assert fs["background_lidar_seeds"] + fs["facade_seeds"] == fs["structure_seeds_fine"]
    # The road under and behind the ego, which no image sees, is kept with its neighbours' colour
    assert 0 < st["unseen_ground_seeds"] < st["ground_seeds"]
    dropped = initial_scene(scene, views, replace(cfg, unseen_ground_reach_m=0.0), sh_degree=0).stats
    assert dropped["unseen_ground_seeds"] == 0 and dropped["ground_seeds"] < st["ground_seeds"]
    # keep_unseen keeps every seed as it is (grey where unseen): nothing left to fill, nothing twice
    as_is = initial_scene(scene, views, replace(cfg, keep_unseen=True), sh_degree=0).stats
    assert as_is["unseen_ground_seeds"] == 0 and as_is["ground_seeds"] < st["ground_seeds"] + 200
    # Over the cap: ground stays whole, structure near and far from the path is thinned alike (far seeds
    # are already sparse; dropping them first blanked the far side of a wide road).
    tiers = st["seeds_by_tier"]
    assert st["background_gaussians"] < cfg.max_background and tiers["far structure"] > 50  # nothing thinned
    ground = tiers["textured ground"] + tiers["plain ground"]
    capped = initial_scene(scene, views, replace(cfg, max_background=ground + (tiers["near structure"] +
                                                                              tiers["far structure"]) // 2),
                           sh_degree=0).stats["seeds_by_tier"]
    assert capped["textured ground"] + capped["plain ground"] == ground
    for name in ("near structure", "far structure"):
        assert 0.3 * tiers[name] < capped[name] < 0.7 * tiers[name], name


def test_unseen_ground_takes_its_seen_neighbours_median_colour_within_reach():
    from nuav2.splat.ground import fill_unseen_ground

    xs, ys = np.meshgrid(np.arange(40) * 0.25, np.arange(20) * 0.25)
    xyz = np.column_stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)])
    rgb = np.full((len(xyz), 3), 0.3)
    rgb[np.isclose(xyz[:, 1], 2.0)] = 0.95  # a lane line along the hole's edge
    seen = xyz[:, 0] < 5.0
    seen[np.isclose(xyz[:, 1], 2.0) & (xyz[:, 0] < 5.0)] = True
    idx, colours = fill_unseen_ground(xyz, rgb, seen, reach_m=2.0, neighbours=16)
    assert set(idx) <= set(np.flatnonzero(~seen)) and len(idx) > 0
    gap = xyz[idx, 0] - 4.75  # distance beyond the last seen column
    assert gap.max() <= 2.0 + 1e-9 and (xyz[~seen, 0] - 4.75).max() > 2.0  # the far part stays out
    np.testing.assert_allclose(colours, 0.3)  # asphalt, not the lane line smeared across the hole
    none, _ = fill_unseen_ground(xyz, rgb, seen, reach_m=0.0, neighbours=16)
    assert len(none) == 0
    all_seen, _ = fill_unseen_ground(xyz, rgb, np.ones(len(xyz), bool), reach_m=2.0, neighbours=16)
    assert len(all_seen) == 0
