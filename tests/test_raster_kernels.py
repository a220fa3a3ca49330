"""Building blocks of the CPU kernels against brute-force oracles: the vectorisable exp, tile
binning (coverage of every contributing pixel, tightness, depth order) and the depth sort."""

from __future__ import annotations

import math

import numpy as np
import torch
from raster_scenes import leaves, pinhole, random_gaussians, random_pose

from nuav2.splat import _binning, _composite, rasterize
from nuav2.splat._fastexp import exp_neg_array
from nuav2.splat.constants import ALPHA_MIN, TILE


def test_fast_exp_accuracy_over_the_kernel_domain():
    s = np.linspace(0.0, 16.6, 400_001, dtype=np.float32)
    approx = exp_neg_array(s).astype(np.float64)
    exact = np.exp(-s.astype(np.float64))
    assert np.max(np.abs(approx - exact) / exact) < 2.5e-7          # ~2 float32 ulp
    assert exp_neg_array(np.array([0.0], np.float32))[0] == 1.0
    s64 = np.linspace(0.0, 16.6, 1001)
    np.testing.assert_allclose(exp_neg_array(s64), np.exp(-s64), rtol=1e-15, atol=0)   # libm exp in float64


def _bin(params, pose, K, width, height):
    out = rasterize(*leaves(params, False), pose, K, width, height)
    m2 = out.meta["means2d"][0].detach().numpy()
    conics = out.meta["conics"][0].detach().numpy()
    depths = out.meta["depths"][0].detach().numpy()
    radii = out.meta["radii"][0].numpy().astype(np.float64)
    opac = torch.sigmoid(params["opacity_logits"]).numpy()
    order = _binning.depth_order(depths, radii)
    packed = np.empty((len(order), _composite.PACKED_WIDTH), np.float32)
    _composite.pack_rows(m2, conics, opac, params["colors"].numpy(), depths, order, packed, 0, len(order))
    alive = np.ones(_binning.n_tiles(width, height), np.uint8)
    offsets, rows = _binning.bin_slab(packed, 0, len(packed), width, height, alive, 2)
    return m2, conics, depths, opac, radii, order, offsets, order[rows], packed


def test_tile_lists_cover_every_contributing_pair_in_depth_order():
    width, height = 53, 37
    pose = random_pose(4)
    params = random_gaussians(300, 4, pose)
    K = pinhole(width, height)
    m2, conics, depths, opac, radii, order, offsets, ids, _packed = _bin(params, pose, K, width, height)
    tiles_x = math.ceil(width / TILE)
    px, py = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    tile_of_pixel = (py // TILE).astype(int) * tiles_x + (px // TILE).astype(int)
    n_exact = 0
    for g in order:
        dx, dy = m2[g, 0] - px, m2[g, 1] - py
        sigma = 0.5 * (conics[g, 0] * dx**2 + conics[g, 2] * dy**2) + conics[g, 1] * dx * dy
        touched = np.unique(tile_of_pixel[(sigma >= 0) & (opac[g] * np.exp(-sigma) >= ALPHA_MIN)])
        n_exact += len(touched)
        for t in touched:
            assert g in ids[offsets[t]:offsets[t + 1]], f"Gaussian {g} missing from tile {t}"
    for t in range(len(offsets) - 1):
        lst = ids[offsets[t]:offsets[t + 1]]
        assert len(set(lst.tolist())) == len(lst)
        assert np.all(np.diff(depths[lst]) >= 0)
    # the per-row ellipse extent is tight: few pairs beyond the pixel-exact ones, far fewer than
    # the rectangular bounding boxes would give
    def n_box_tiles(m, r, size):
        return math.ceil(min(size, m + r) / TILE) - int(max(0.0, m - r) // TILE)

    n_boxes = sum(n_box_tiles(m2[g, 0], radii[g, 0], width) * n_box_tiles(m2[g, 1], radii[g, 1], height)
                  for g in order)
    assert n_exact <= len(ids) <= 1.1 * n_exact < n_boxes


def test_depth_order_is_a_stable_sort_of_visible_gaussians():
    rng = np.random.default_rng(1)
    depths = rng.choice([1.0, 2.5, 3.0, 7.0], 500).astype(np.float32)
    radii = np.where(rng.random((500, 1)) < 0.7, 3.0, 0.0) * np.ones((1, 2))
    visible = np.flatnonzero(radii[:, 0] > 0)
    expected = visible[np.argsort(depths[visible], kind="stable")]
    assert np.array_equal(_binning.depth_order(depths, radii), expected)


def test_binning_skips_stopped_tiles_and_slabs_partition_the_rows():
    width, height = 53, 37
    pose = random_pose(5)
    params = random_gaussians(300, 5, pose)
    K = pinhole(width, height)
    _m2, _con, _dep, _op, _radii, order, offsets, ids, packed = _bin(params, pose, K, width, height)
    n_tiles = len(offsets) - 1
    alive = (np.arange(n_tiles) % 3 != 0).astype(np.uint8)          # every third tile has stopped
    bounds = [0, 7, 120, len(order)]
    per_tile = {t: [] for t in range(n_tiles)}
    for lo, hi in zip(bounds[:-1], bounds[1:]):
        off, rows = _binning.bin_slab(packed, lo, hi, width, height, alive, 2)
        assert ((rows >= lo) & (rows < hi)).all()
        for t in range(n_tiles):
            per_tile[t] += rows[off[t]:off[t + 1]].tolist()
    for t in range(n_tiles):
        full = ids[offsets[t]:offsets[t + 1]].tolist()
        assert [order[r] for r in per_tile[t]] == (full if alive[t] else [])


def test_an_opaque_foreground_stops_after_the_first_depth_slab():
    """Three opaque splats in front of everything stop every pixel: the rows behind them are never
    binned, and the image (and gradients) still equal the dense reference's."""
    from nuav2.splat._stages import record_stages
    from nuav2.splat.dense_reference import rasterize_dense

    width, height = 40, 30
    K = pinhole(width, height)
    params = random_gaussians(3000, 6, depth=(3.0, 9.0))
    for k in params:
        params[k] = params[k].clone()
    params["means"][:3] = torch.tensor([[0.0, 0.0, 1.0], [0.01, 0.0, 1.1], [0.0, 0.01, 1.2]])
    params["log_scales"][:3] = 2.0
    params["opacity_logits"][:3] = 12.0
    with record_stages() as counts:
        out = rasterize(*leaves(params, False), np.eye(4), K, width, height)
    assert counts["depth_slabs"][0] == 1
    assert counts["tile_pairs"][0] < 0.2 * 3000
    ref = rasterize_dense(*leaves(params, False), np.eye(4), K, width, height)
    assert (out.rgb - ref.rgb).abs().max() < 1e-5 and (out.alpha - ref.alpha).abs().max() < 1e-5
