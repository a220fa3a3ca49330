"""The camera-only mapping model: images + calibration -> MapTR-format vectors (and aux maps).

backbone (from scratch) -> depth-based lift into the LIDAR_TOP BEV grid -> BEV encoder ->
vector decoder; two 1x1 heads give MapTRv2's auxiliary dense outputs (BEV segmentation of the
map lines, and their perspective-view segmentation on the image features).
"""

from __future__ import annotations

from pathlib import Path

import torch
from torch import nn

from nuav2.mapping.backbone import ImageBackbone
from nuav2.mapping.config import MapModelConfig
from nuav2.mapping.head import BEVEncoder, VectorDecoder
from nuav2.mapping.lift import LiftSplat

# The weights' layout, in every run's fingerprint: runs and checkpoints of another layout retrain instead
# of being reused. 2: the decoder's per-point index embedding (323a7ba).
ARCHITECTURE = 2


def load_weights(model: nn.Module, state: dict, source: str | Path) -> None:
    """``model.load_state_dict(state)``, or a ValueError naming ``source`` when the weights are of
    another layout (saved before an architecture change) instead of torch's list of keys."""
    try:
        model.load_state_dict(state)
    except RuntimeError:
        ours = set(model.state_dict())
        missing, extra = sorted(ours - set(state)), sorted(set(state) - ours)
        what = "; ".join(f"{n} {kind} (e.g. {keys[0]})" for kind, keys, n in
                         (("missing", missing, len(missing)), ("unexpected", extra, len(extra))) if keys)
        what = what or "tensor shapes differ"
        raise ValueError(f"{source}: weights of another model layout (saved by an older nuav2, model "
                         f"architecture {ARCHITECTURE} now): retrain ({what})") from None


class MapModel(nn.Module):
    def __init__(self, cfg: MapModelConfig) -> None:
        super().__init__()
        self.cfg = cfg
        k = len(cfg.classes)
        self.backbone = ImageBackbone(
            cfg.stem_channels, cfg.stage_channels, cfg.feat_channels, cfg.feat_stride
        )
        self.lift = LiftSplat(cfg, cfg.feat_channels)
        self.bev_encoder = BEVEncoder(cfg.feat_channels, cfg.bev_channels)
        self.decoder = VectorDecoder(cfg, cfg.bev_channels + (k if cfg.decoder_sees_seg else 0))
        self.bev_seg = nn.Conv2d(cfg.bev_channels, k, 1)
        self.pv_seg = nn.Conv2d(cfg.feat_channels, k, 1)
        prior = -4.6  # sigmoid ~ 1 %: map lines cover few pixels
        for head in (self.bev_seg, self.pv_seg):
            nn.init.constant_(head.bias, prior)

    def forward(
        self, img: torch.Tensor, lidar2img: torch.Tensor, img_hw: torch.Tensor, one2many: bool = False
    ) -> dict:
        """``img`` (B, N, 3, H, W) uint8, ``lidar2img`` (B, N, 4, 4) for its pixels, ``img_hw`` (B, N, 2)."""
        B, N = img.shape[:2]
        feats = self.backbone(img.flatten(0, 1))
        h, w = feats.shape[-2:]
        bev, depth = self.lift(feats.view(B, N, -1, h, w), lidar2img, img_hw)
        bev = self.bev_encoder(bev)
        g = self.cfg.decoder_grad_scale
        to_decoder = bev if g == 1.0 else bev.detach() if g == 0.0 else bev * g + bev.detach() * (1.0 - g)
        seg = self.bev_seg(bev)
        if self.cfg.decoder_sees_seg:
            to_decoder = torch.cat([to_decoder, seg.detach()], 1)
        return {
            "layers": self.decoder(to_decoder, one2many),
            "bev_seg": seg,
            "pv_seg": self.pv_seg(feats).view(B, N, -1, h, w),
            "depth": depth,
        }
