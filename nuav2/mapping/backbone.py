"""A light residual CNN trained from scratch: camera images -> stride-4 or stride-8 feature maps.

Four stages (strides 2, 4, 8, 16) of basic residual blocks, then a top-down FPN: the stride-16
map is upsampled onto the stride-8 one and, for ``stride=4``, that onto the stride-4 one, so the
output features see a wide context. Stride 4 matters for the lift: a feature row of a camera
1.5 m above the road spans ``r^2 / 1.5 * (stride / focal)`` metres of ground at range r, and
MapTRv2's LSS (stride 16 on 0.5x nuScenes images) samples 0.025 rad per feature; stride 4 at a
158 px focal length matches that, stride 8 at 100 px is three times coarser.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

STRIDE = 8  # the default output stride (MapModelConfig.feat_stride)
# ImageNet statistics only normalise the input range; nothing here is pretrained.
_MEAN = (0.485, 0.456, 0.406)
_STD = (0.229, 0.224, 0.225)


def conv_bn(cin: int, cout: int, stride: int = 1, k: int = 3) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(cin, cout, k, stride, k // 2, bias=False), nn.BatchNorm2d(cout), nn.ReLU(inplace=True)
    )


class BasicBlock(nn.Module):
    def __init__(self, cin: int, cout: int, stride: int = 1) -> None:
        super().__init__()
        self.conv1 = conv_bn(cin, cout, stride)
        self.conv2 = nn.Sequential(nn.Conv2d(cout, cout, 3, 1, 1, bias=False), nn.BatchNorm2d(cout))
        self.skip = (
            nn.Sequential(nn.Conv2d(cin, cout, 1, stride, bias=False), nn.BatchNorm2d(cout))
            if stride != 1 or cin != cout
            else nn.Identity()
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.relu(self.conv2(self.conv1(x)) + self.skip(x), inplace=True)


class ImageBackbone(nn.Module):
    """(N, 3, H, W) uint8 or float images -> (N, out_channels, ceil(H/s), ceil(W/s)), s = ``stride``."""

    def __init__(self, stem: int, stages: tuple[int, ...], out_channels: int, stride: int = STRIDE) -> None:
        super().__init__()
        if len(stages) != 3:
            raise ValueError(f"stage_channels must hold 3 widths (strides 4, 8, 16), got {stages}")
        if stride not in (4, 8):
            raise ValueError(f"stride must be 4 or 8, got {stride}")
        self.stride = stride
        c4, c8, c16 = stages
        self.stem = nn.Sequential(conv_bn(3, stem, 2), conv_bn(stem, stem))
        self.s4 = nn.Sequential(BasicBlock(stem, c4, 2), BasicBlock(c4, c4))
        self.s8 = nn.Sequential(BasicBlock(c4, c8, 2), BasicBlock(c8, c8))
        self.s16 = nn.Sequential(BasicBlock(c8, c16, 2), BasicBlock(c16, c16))
        self.lat8 = nn.Conv2d(c8, out_channels, 1)
        self.lat16 = nn.Conv2d(c16, out_channels, 1)
        self.lat4 = nn.Conv2d(c4, out_channels, 1) if stride == 4 else None
        self.out = conv_bn(out_channels, out_channels)
        self.register_buffer("mean", torch.tensor(_MEAN).view(1, 3, 1, 1) * 255.0, persistent=False)
        self.register_buffer("std", torch.tensor(_STD).view(1, 3, 1, 1) * 255.0, persistent=False)

    def forward(self, img: torch.Tensor) -> torch.Tensor:
        x = (img.float() - self.mean) / self.std
        f4 = self.s4(self.stem(x))
        f8 = self.s8(f4)
        f16 = self.s16(f8)
        up = F.interpolate(self.lat16(f16), size=f8.shape[-2:], mode="bilinear", align_corners=False)
        top = self.lat8(f8) + up
        if self.lat4 is not None:
            up = F.interpolate(top, size=f4.shape[-2:], mode="bilinear", align_corners=False)
            top = self.lat4(f4) + up
        return self.out(top)
