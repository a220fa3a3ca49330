"""The depth-based lift: frustum points land in the right BEV cell (oracle: an independent ray
construction from K and the camera pose), padding and out-of-patch points are dropped, and the
splat conserves mass and places features in their cell."""

from __future__ import annotations

import numpy as np
import torch

from nuav2.geometry import T_inverse
from nuav2.mapping.backbone import STRIDE
from nuav2.mapping.config import MapModelConfig
from nuav2.mapping.lift import depth_bin_centres, frustum_cells, splat
from nuav2.rig import load_rig

CFG = MapModelConfig()


def _nuscenes_lidar2img(channel: str, scale: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """lidar2img of a nuScenes camera with the nuScenes LIDAR_TOP extrinsic; also K and lidar_T_cam."""
    rig = load_rig("nuscenes", scale)
    cam = rig.camera(channel)
    ego_T_lidar = rig.lidar("LIDAR_TOP").ego_T_lidar
    lidar_T_cam = T_inverse(ego_T_lidar) @ cam.ego_T_cam
    K4 = np.eye(4)
    K4[:3, :3] = cam.K
    return K4 @ T_inverse(lidar_T_cam), cam.K, lidar_T_cam


def test_frustum_cells_match_an_independent_ray_construction():
    scale = 0.08
    l2i, K, lidar_T_cam = _nuscenes_lidar2img("CAM_FRONT_LEFT", scale)
    H, W = 72, 128
    h, w = -(-H // STRIDE), -(-W // STRIDE)
    cell, valid = frustum_cells(CFG, torch.from_numpy(l2i)[None, None], torch.tensor([[[H, W]]]), (h, w))
    assert cell.shape == valid.shape == (1, 1, CFG.depth_bins, h, w)
    depth = depth_bin_centres(CFG).numpy()
    u = np.arange(w) * STRIDE + (STRIDE - 1) / 2
    v = np.arange(h) * STRIDE + (STRIDE - 1) / 2
    uu, vv = np.meshgrid(u, v)
    rays = np.stack([(uu - K[0, 2]) / K[0, 0], (vv - K[1, 2]) / K[1, 1], np.ones_like(uu)], -1)  # z = 1
    pts_cam = depth[:, None, None, None] * rays[None]  # z-depth d
    pts = pts_cam @ lidar_T_cam[:3, :3].T + lidar_T_cam[:3, 3]
    hx, hy = CFG.half_extent_xy
    fx, fy = (pts[..., 0] + hx) / CFG.bev_cell_m, (pts[..., 1] + hy) / CFG.bev_cell_m
    rows, cols = CFG.bev_shape
    inside = (fx >= 0) & (fx < cols) & (fy >= 0) & (fy < rows)
    inside &= (pts[..., 2] >= CFG.lift_z_range_m[0]) & (pts[..., 2] < CFG.lift_z_range_m[1])
    inside &= (uu < W)[None] & (vv < H)[None]
    # points within 1e-6 cells of a cell boundary may round either way
    clear = (np.abs(fx - np.round(fx)) > 1e-6) & (np.abs(fy - np.round(fy)) > 1e-6)
    got_valid = valid[0, 0].numpy()
    assert np.array_equal(got_valid[clear], inside[clear])
    expected = np.floor(fy).astype(int) * cols + np.floor(fx).astype(int)
    both = got_valid & inside & clear
    assert both.sum() > 100  # the camera sees a good part of the patch
    assert np.array_equal(cell[0, 0].numpy()[both], expected[both])


def test_padding_pixels_and_points_behind_the_patch_are_invalid():
    l2i, _, _ = _nuscenes_lidar2img("CAM_BACK", 0.08)
    H, W = 72, 128
    h, w = -(-H // STRIDE), -(-W // STRIDE)
    real_hw = torch.tensor([[[40, 64]]])  # the image covers only the top-left part of the padded canvas
    _, valid = frustum_cells(CFG, torch.from_numpy(l2i)[None, None], real_hw, (h, w))
    v = np.arange(h) * STRIDE + (STRIDE - 1) / 2
    u = np.arange(w) * STRIDE + (STRIDE - 1) / 2
    outside = (v[:, None] >= 40) | (u[None, :] >= 64)
    assert not valid[0, 0].numpy()[:, outside].any()
    # far depths leave the 60 m x 30 m patch: the deepest bins of the rear camera are all invalid
    assert not valid[0, 0, -1].any()


def test_splat_conserves_mass_and_places_features_in_their_cell():
    B, N, D, h, w, C = 1, 2, 3, 2, 2, 4
    rows, cols = 5, 4
    gen = torch.Generator().manual_seed(0)
    depth = torch.rand(B, N, D, h, w, generator=gen).softmax(dim=2)
    ctx = torch.rand(B, N, C, h, w, generator=gen)
    cell = torch.randint(0, rows * cols, (B, N, D, h, w), generator=gen)
    valid = torch.rand(B, N, D, h, w, generator=gen) > 0.3
    bev = splat(depth, ctx, cell, valid, (rows, cols))
    assert bev.shape == (B, C, rows, cols)
    expected_total = (depth.unsqueeze(3) * ctx.unsqueeze(2) * valid.unsqueeze(3)).sum(dim=(1, 2, 4, 5))
    torch.testing.assert_close(bev.sum(dim=(2, 3)), expected_total)
    # one valid point: its feature vector appears in its cell only
    valid = torch.zeros_like(valid)
    valid[0, 1, 2, 1, 0] = True
    c = int(cell[0, 1, 2, 1, 0])
    bev = splat(depth, ctx, cell, valid, (rows, cols))
    torch.testing.assert_close(bev[0, :, c // cols, c % cols], depth[0, 1, 2, 1, 0] * ctx[0, 1, :, 1, 0])
    assert torch.count_nonzero(bev.abs().sum(1)) == 1
