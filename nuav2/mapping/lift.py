"""Depth-based lift into BEV (Lift-Splat-Shoot, the view transform MapTRv2 uses), calibration-aware.

Each image feature pixel predicts a distribution over ``depth_bins`` depths and a context
vector; their outer product is placed at the 3-D points those depths give along the pixel's
ray, found through the inverse of the camera's own ``lidar2img`` (intrinsics, extrinsics and
the camera's ego pose at its capture time), and summed into the BEV cell under each point
(LIDAR_TOP frame, MapTR's patch). Nothing assumes a ground plane: where a rig puts a road
pixel is learned through the depth distribution, as in MapTRv2, so a model trained on one rig
meets a different depth-per-pixel on another.
"""

from __future__ import annotations

import torch
from torch import nn

from nuav2.mapping.config import MapModelConfig


def depth_bin_centres(cfg: MapModelConfig) -> torch.Tensor:
    step = (cfg.depth_max_m - cfg.depth_min_m) / cfg.depth_bins
    return cfg.depth_min_m + step * (torch.arange(cfg.depth_bins, dtype=torch.float64) + 0.5)


def frustum_cells(
    cfg: MapModelConfig, lidar2img: torch.Tensor, img_hw: torch.Tensor, feat_hw: tuple[int, int]
) -> tuple[torch.Tensor, torch.Tensor]:
    """BEV cell of every (camera, depth bin, feature pixel) point and whether it counts.

    ``lidar2img`` (B, N, 4, 4) maps LIDAR_TOP to resized-image pixels; ``img_hw`` (B, N, 2) is each
    image's real size (pixels beyond it are padding). Returns flat cell indices (B, N, D, h, w)
    into a (rows, cols) grid and a validity mask of the same shape (inside the image, the patch
    and the height range).
    """
    B, N = lidar2img.shape[:2]
    h, w = feat_hw
    dev = lidar2img.device
    depth = depth_bin_centres(cfg).to(dev)  # (D,)
    s = cfg.feat_stride
    u = torch.arange(w, dtype=torch.float64, device=dev) * s + (s - 1) / 2.0
    v = torch.arange(h, dtype=torch.float64, device=dev) * s + (s - 1) / 2.0
    vv, uu = torch.meshgrid(v, u, indexing="ij")  # (h, w)
    d = depth.view(-1, 1, 1)
    pix = torch.stack([uu * d, vv * d, d.expand(-1, h, w), torch.ones_like(uu).expand(len(depth), h, w)], -1)
    img_T_lidar = lidar2img.double()
    lidar_T_img = torch.linalg.inv(img_T_lidar)  # (B, N, 4, 4)
    pts = torch.einsum("bnij,dhwj->bndhwi", lidar_T_img, pix)[..., :3]  # (B, N, D, h, w, 3)
    hx, hy = cfg.half_extent_xy
    rows, cols = cfg.bev_shape
    col = torch.floor((pts[..., 0] + hx) / cfg.bev_cell_m).long()
    row = torch.floor((pts[..., 1] + hy) / cfg.bev_cell_m).long()
    z_lo, z_hi = cfg.lift_z_range_m
    inside_img = (uu[None, None, None] < img_hw[:, :, 1, None, None, None].double()) & (
        vv[None, None, None] < img_hw[:, :, 0, None, None, None].double()
    )
    valid = (
        (col >= 0)
        & (col < cols)
        & (row >= 0)
        & (row < rows)
        & (pts[..., 2] >= z_lo)
        & (pts[..., 2] < z_hi)
        & inside_img
    )
    return row.clamp(0, rows - 1) * cols + col.clamp(0, cols - 1), valid


def splat(
    depth: torch.Tensor,
    ctx: torch.Tensor,
    cell: torch.Tensor,
    valid: torch.Tensor,
    bev_shape: tuple[int, int],
) -> torch.Tensor:
    """Sum depth (B, N, D, h, w) x context (B, N, C, h, w) outer products into their BEV cells.

    ``cell`` / ``valid`` as :func:`frustum_cells` returns them; out (B, C, rows, cols). Only the valid
    frustum points are multiplied out (most of a frustum leaves the patch or the height range), so
    the (points, C) volume is never built for the rest: at stride 4 this is 3x faster than the
    dense outer product.
    """
    B, N, D, h, w = depth.shape
    C = ctx.shape[2]
    rows, cols = bev_shape
    sel = valid.reshape(-1).nonzero().squeeze(1)  # flat (b, n, d, y, x) of the valid points
    hw = h * w
    bn = torch.div(sel, D * hw, rounding_mode="floor")
    pix = bn * hw + sel % hw  # flat (b, n, y, x)
    target = torch.div(bn, N, rounding_mode="floor") * rows * cols + cell.reshape(-1)[sel]
    ctx_flat = ctx.permute(0, 1, 3, 4, 2).reshape(B * N * hw, C)
    vol = depth.reshape(-1)[sel].unsqueeze(1) * ctx_flat[pix]
    bev = ctx.new_zeros(B * rows * cols, C).index_add_(0, target, vol)
    return bev.view(B, rows, cols, C).permute(0, 3, 1, 2).contiguous()


class LiftSplat(nn.Module):
    """Image features (B, N, C_in, h, w) -> BEV features (B, feat_channels, rows, cols)."""

    def __init__(self, cfg: MapModelConfig, in_channels: int) -> None:
        super().__init__()
        self.cfg = cfg
        self.depth_net = nn.Sequential(
            nn.Conv2d(in_channels, in_channels, 3, 1, 1),
            nn.BatchNorm2d(in_channels),
            nn.ReLU(inplace=True),
            nn.Conv2d(in_channels, cfg.depth_bins + cfg.feat_channels, 1),
        )

    def forward(
        self, feats: torch.Tensor, lidar2img: torch.Tensor, img_hw: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Returns the BEV features and the depth distributions (B, N, D, h, w)."""
        B, N, C, h, w = feats.shape
        out = self.depth_net(feats.flatten(0, 1)).view(B, N, -1, h, w)
        depth = out[:, :, : self.cfg.depth_bins].softmax(dim=2)
        ctx = out[:, :, self.cfg.depth_bins :]
        with torch.no_grad():
            cell, valid = frustum_cells(self.cfg, lidar2img, img_hw, (h, w))
        return splat(depth, ctx, cell, valid, self.cfg.bev_shape), depth
