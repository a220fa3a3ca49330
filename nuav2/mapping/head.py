"""BEV encoder and the vector decoder: queries -> MapTR fixed-point polylines with class scores.

The decoder is MapTR's idea at CPU size: each query is one map element of ``num_points`` points
(normalised to the patch, [0, 1]^2). Every layer samples the BEV features at the query's current
points (bilinear), updates the query from them (shape-aware: the point features are
concatenated), lets queries attend to each other and to the whole BEV pooled to 2 m tokens
(DETR's cross-attention: a query far from every line still learns where lines are), and
refines every point by an offset in logit space (iterative refinement as in Deformable DETR).
Each layer predicts classes and points, so each can be supervised (deep supervision).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from nuav2.mapping.backbone import BasicBlock, conv_bn
from nuav2.mapping.config import MapModelConfig

EPS = 1e-4
MEMORY_POOL = 4  # the decoder's global view: BEV pooled 4x (2 m cells on the default 0.5 m grid)


def inverse_sigmoid(x: torch.Tensor) -> torch.Tensor:
    x = x.clamp(EPS, 1 - EPS)
    return torch.log(x / (1 - x))


class BEVEncoder(nn.Module):
    """(B, C_in, R, C) -> (B, bev_channels, R, C): full-resolution conv, a half-resolution residual
    stage for context, and their sum."""

    def __init__(self, cin: int, ch: int) -> None:
        super().__init__()
        self.full = nn.Sequential(conv_bn(cin, ch), conv_bn(ch, ch))
        self.coarse = nn.Sequential(BasicBlock(ch, ch, 2), BasicBlock(ch, ch))
        self.fuse = conv_bn(ch, ch)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        f = self.full(x)
        h = F.interpolate(self.coarse(f), size=f.shape[-2:], mode="bilinear", align_corners=False)
        return self.fuse(f + h)


def _mlp(cin: int, hidden: int, cout: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(cin, hidden), nn.ReLU(inplace=True), nn.Linear(hidden, cout))


class DecoderLayer(nn.Module):
    def __init__(self, cfg: MapModelConfig, bev_channels: int) -> None:
        super().__init__()
        d, p = cfg.decoder_dim, cfg.num_points
        self.point_in = nn.Linear(bev_channels + 2, d // 4)
        # which of the query's points this is (MapTR's point queries): without it a point's offset knew
        # only where the point is, and refinement layers could not put a query's points in GT order
        self.point_embed = nn.Parameter(torch.randn(p, d // 4) * 0.1)
        self.gather = nn.Linear(p * (d // 4), d)
        self.norm1 = nn.LayerNorm(d)
        self.attn = nn.MultiheadAttention(d, cfg.decoder_heads, batch_first=True)
        self.norm2 = nn.LayerNorm(d)
        self.pos = _mlp(2 * p, d, d)  # where the query's points are, for attending to the BEV
        self.cross = nn.MultiheadAttention(d, cfg.decoder_heads, batch_first=True)
        self.norm_cross = nn.LayerNorm(d)
        self.ffn = _mlp(d, 2 * d, d)
        self.norm3 = nn.LayerNorm(d)
        self.offset = _mlp(d + d // 4, d, 2)
        self.cls = nn.Linear(d, len(cfg.classes))
        nn.init.zeros_(self.offset[-1].weight)
        nn.init.zeros_(self.offset[-1].bias)

    def _offsets(self, pf: torch.Tensor, q: torch.Tensor) -> torch.Tensor:
        """``self.offset`` of [point feature, query] per point, with the first layer split: its query
        half is computed once per query, not once per point (20x less work, the same function)."""
        first, rest = self.offset[0], self.offset[1:]
        k = pf.shape[-1]
        h = F.linear(pf, first.weight[:, :k], first.bias) + F.linear(q, first.weight[:, k:]).unsqueeze(2)
        return rest(h)

    def forward(
        self,
        q: torch.Tensor,
        pts: torch.Tensor,
        bev: torch.Tensor,
        memory: torch.Tensor,
        attn_mask: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``memory`` (B, M, d): the coarse BEV as tokens (with their position), for global context."""
        B, Q, P, _ = pts.shape
        grid = pts * 2.0 - 1.0  # x -> columns, y -> rows (align_corners=False: cell centres)
        feat = F.grid_sample(bev, grid, mode="bilinear", padding_mode="zeros", align_corners=False)
        feat = feat.permute(0, 2, 3, 1)  # (B, Q, P, C)
        pf = F.relu(self.point_in(torch.cat([feat, pts], -1)) + self.point_embed)  # (B, Q, P, d/4)
        q = self.norm1(q + self.gather(pf.flatten(2)))
        q = self.norm2(q + self.attn(q, q, q, attn_mask=attn_mask, need_weights=False)[0])
        qp = q + self.pos(pts.flatten(2))
        q = self.norm_cross(q + self.cross(qp, memory, memory, need_weights=False)[0])
        q = self.norm3(q + self.ffn(q))
        delta = self._offsets(pf, q)
        new_pts = torch.sigmoid(inverse_sigmoid(pts) + delta)
        return q, new_pts, self.cls(q)


class VectorDecoder(nn.Module):
    """BEV features -> per layer (class logits (B, Q, K), points (B, Q, P, 2) in [0, 1])."""

    def __init__(self, cfg: MapModelConfig, bev_channels: int) -> None:
        super().__init__()
        self.num_one2one = cfg.num_queries
        total = cfg.num_queries + cfg.one2many_queries
        self.query = nn.Parameter(torch.randn(total, cfg.decoder_dim) * 0.1)
        self.ref_logits = nn.Parameter(self._initial_points(total, cfg.num_points))
        self.layers = nn.ModuleList(DecoderLayer(cfg, bev_channels) for _ in range(cfg.decoder_layers))
        rows, cols = cfg.bev_shape
        self.memory_in = nn.Linear(bev_channels, cfg.decoder_dim)
        tokens = -(-rows // MEMORY_POOL) * -(-cols // MEMORY_POOL)
        self.memory_pos = nn.Parameter(torch.randn(tokens, cfg.decoder_dim) * 0.1)
        # MapTRv2's hybrid matching: the one-to-many group never attends to (or is seen by) the other.
        group = torch.arange(total) >= cfg.num_queries
        self.register_buffer("group_mask", group[:, None] != group[None, :], persistent=False)

    @staticmethod
    def _initial_points(Q: int, P: int) -> torch.Tensor:
        """Short straight segments spread over the patch in both directions (a deterministic layout)."""
        g = torch.Generator().manual_seed(0)
        centre = 0.1 + 0.8 * torch.rand(Q, 2, generator=g)
        angle = torch.rand(Q, generator=g) * math.pi
        direction = torch.stack([torch.cos(angle), torch.sin(angle) * 0.5], -1)  # y spans twice the metres
        t = torch.linspace(-0.08, 0.08, P)
        pts = centre[:, None, :] + t[None, :, None] * direction[:, None, :]
        return inverse_sigmoid(pts.clamp(0.02, 0.98))

    def forward(self, bev: torch.Tensor, one2many: bool = False) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """Per layer (logits, points) of the one-to-one queries, followed (with ``one2many``, in
        training) by those of the one-to-many group; without it that group is not run at all."""
        B = bev.shape[0]
        n = self.query.shape[0] if one2many else self.num_one2one
        q = self.query[:n].unsqueeze(0).expand(B, -1, -1)
        pts = torch.sigmoid(self.ref_logits[:n]).unsqueeze(0).expand(B, -1, -1, -1)
        mask = self.group_mask[:n, :n] if n > self.num_one2one else None
        coarse = F.avg_pool2d(bev, MEMORY_POOL, ceil_mode=True).flatten(2).transpose(1, 2)  # (B, M, C)
        memory = self.memory_in(coarse) + self.memory_pos
        outs = []
        for layer in self.layers:
            q, pts_new, logits = layer(q, pts, bev, memory, mask)
            outs.append((logits, pts_new))
            pts = pts_new.detach()
        return outs
