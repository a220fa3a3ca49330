"""How many Gaussians a scene gets, and which seeds stay when there are too many.

Seeds follow the scene: ground seeds cover the area the trajectory sees, on a fine grid only
where the ground has texture (lane paint, crossings, kerbs) and merged into coarser discs where
it is plain (:func:`merge_plain_ground`); LiDAR and facade seeds follow what stands (facades, parked
cars, poles), merged into coarser ones where the structure is plain (:func:`merge_plain_structure`);
each moving track brings its own. The densification budget is the seed count times a
growth factor plus a share per moving track (:func:`scene_budget`), so a plain, empty road ends
with fewer Gaussians than a busy junction. When seeds exceed the cap they are kept by priority
(:func:`keep_by_priority`): textured ground (paint) first, then plain ground, then LiDAR and
facade seeds (near and far from the path alike: far ones are already sparse); the tier that
straddles the cap is thinned uniformly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nuav2.cells import cell_means, unique_cells

F64 = np.ndarray

TIER_PAINT, TIER_GROUND, TIER_NEAR, TIER_FAR = 0, 1, 2, 3
TIER_NAMES = ("textured ground", "plain ground", "near structure", "far structure")


@dataclass(frozen=True)
class BudgetConfig:
    """Seed merging and the densification budget."""

    merge_levels: int = 2  # plain ground merges up to 2^levels x the seed spacing
    merge_tol: float = 0.05  # merge a 2x2 block when no child's colour is further than this from the mean
    structure_merge_levels: int = 1  # plain LiDAR / facade seeds: up to 2^levels x their voxel (0: never)
    growth: float = 1.25  # densification budget = seeds x growth ...
    per_moving_track: int = 1500  # ... + this many per moving track
    min_budget: int = 20_000
    max_budget: int = 150_000


@dataclass
class GroundSeeds:
    """Ground seeds with their grid cell (integer, at the finest spacing), size in cells and colour."""

    xyz: F64  # (N, 3)
    rgb: np.ndarray  # (N, 3) float in [0, 1]
    cell: np.ndarray  # (N, 2) int64 lower-left cell at the finest spacing
    size: np.ndarray  # (N,) int64 side in finest cells (1, 2, 4, ...)

    def __len__(self) -> int:
        return len(self.xyz)


def merge_plain_ground(seeds: GroundSeeds, levels: int, tol: float) -> GroundSeeds:
    """Merge every complete 2x2 block of equal-size seeds whose colours agree within ``tol`` into one seed
    (mean position and colour, twice the size), ``levels`` times. Paint edges, crossings and any other
    texture keep their fine seeds."""
    out = seeds
    for level in range(levels):
        size = 1 << level
        cand = np.flatnonzero(out.size == size)
        if len(cand) < 4:
            break
        block = out.cell[cand] // (2 * size)
        key = block[:, 0] * 1_000_003 + block[:, 1]
        order = np.argsort(key, kind="stable")
        cand, key = cand[order], key[order]
        uniq, start, count = np.unique(key, return_index=True, return_counts=True)
        full = np.flatnonzero(count == 4)
        if len(full) == 0:
            break
        members = cand[start[full][:, None] + np.arange(4)[None, :]]  # (B, 4)
        rgb = out.rgb[members]
        mean = rgb.mean(1)
        plain = np.abs(rgb - mean[:, None]).max(axis=(1, 2)) <= tol
        if not plain.any():
            break
        members, mean = members[plain], mean[plain]
        gone = np.zeros(len(out), bool)
        gone[members.ravel()] = True
        keep = ~gone
        new_cell = (out.cell[members[:, 0]] // (2 * size)) * (2 * size)
        out = GroundSeeds(np.concatenate([out.xyz[keep], out.xyz[members].mean(1)]),
                          np.concatenate([out.rgb[keep], mean]),
                          np.concatenate([out.cell[keep], new_cell]),
                          np.concatenate([out.size[keep], np.full(len(members), 2 * size, np.int64)]))
    return out


def merge_plain_structure(points: F64, rgb: np.ndarray, band: np.ndarray, voxel_m: float, levels: int,
                          tol: float) -> tuple[F64, np.ndarray, np.ndarray]:
    """Merge LiDAR and facade seeds of plain structure into coarser ones, ``levels`` times: at level l
    the seeds of distance band k share a voxel of ``voxel_m * 2**(k + l + 1)``; a voxel merges into one
    seed (mean position and colour) when it holds at least two seeds, all of size ``2**l`` (no finer
    texture inside) and no colour further than ``tol`` from their mean. Returns points, colours and
    each seed's size in its band's voxels (1, 2, 4, ...); kNN scales then widen with the spacing."""
    pts, col = np.asarray(points, np.float64), np.asarray(rgb, np.float64)
    band, size = np.asarray(band, np.int64), np.ones(len(pts), np.int64)
    for level in range(levels):
        if len(pts) < 2:
            break
        cell_m = voxel_m * 2.0 ** (band + level + 1)
        # band, then the voxel at that band's size: one unit cell per (band, voxel)
        first, inverse, counts = unique_cells(np.column_stack([band, pts / cell_m[:, None]]), 1.0)
        n = len(counts)
        mean = cell_means(col, inverse, counts)
        spread = np.zeros(n)
        np.maximum.at(spread, inverse, np.abs(col - mean[inverse]).max(1))
        finer = np.zeros(n, bool)
        finer[inverse[size != (1 << level)]] = True
        merge = (counts >= 2) & ~finer & (spread <= tol)
        if not merge.any():
            break
        gone = merge[inverse]
        pts = np.concatenate([pts[~gone], cell_means(pts, inverse, counts)[merge]])
        col = np.concatenate([col[~gone], mean[merge]])
        band = np.concatenate([band[~gone], band[first[merge]]])
        size = np.concatenate([size[~gone], np.full(int(merge.sum()), 2 << level, np.int64)])
    return pts, col.astype(np.asarray(rgb).dtype, copy=False), size


def keep_by_priority(tier: np.ndarray, cap: int, rng: np.random.Generator) -> np.ndarray:
    """Sorted indices of at most ``cap`` items: whole tiers in ascending order while they fit, then a
    uniform sample of the tier that straddles the cap."""
    tier = np.asarray(tier)
    if len(tier) <= cap:
        return np.arange(len(tier))
    keep, room = [], int(cap)
    for t in np.unique(tier):
        idx = np.flatnonzero(tier == t)
        if len(idx) <= room:
            keep.append(idx)
            room -= len(idx)
        else:
            if room > 0:
                keep.append(np.sort(rng.choice(idx, room, replace=False)))
            break
    return np.sort(np.concatenate(keep)) if keep else np.zeros(0, np.int64)


def scene_budget(n_seeds: int, n_moving: int, cfg: BudgetConfig) -> int:
    """Densification budget: seeds x growth + a share per moving track, clipped to [min, max]."""
    b = int(round(cfg.growth * n_seeds)) + cfg.per_moving_track * int(n_moving)
    return int(np.clip(b, cfg.min_budget, cfg.max_budget))
