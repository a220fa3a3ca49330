"""Configuration of the small mapping model and of one training run (JSON round-trippable, hashable).

Sizes are chosen for CPU training: images resized so the cameras' focal length is
``input_focal_px`` (about 1/13 of a nuScenes camera), a 0.5 m BEV grid over MapTR's 60 m x
30 m patch, 60 vector queries of 20 points. The run's fingerprint keys the benchmark's cache,
so a changed knob retrains and an unchanged one reuses a finished run.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, field, fields

from nuav2.maptr.vectorize import CLASSES, DEFAULT_PATCH

FEAT_STRIDES = (4, 8)  # where the backbone's features may leave (its FPN levels)


def _check_positive(obj, names: tuple[str, ...]) -> None:
    for name in names:
        v = getattr(obj, name)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not v > 0:
            raise ValueError(f"{type(obj).__name__}.{name} must be > 0, got {v!r}")


@dataclass(frozen=True)
class MapModelConfig:
    """Architecture: backbone -> depth-based lift into BEV (LSS) -> BEV encoder -> vector decoder."""

    classes: tuple[str, ...] = CLASSES
    num_points: int = 20  # fixed points per polyline (MapTR)
    patch: tuple[float, float] = DEFAULT_PATCH  # (forward, right) metres, LIDAR_TOP frame
    input_focal_px: float = 100.0  # images are resized so their median focal length is this
    stem_channels: int = 24
    stage_channels: tuple[int, ...] = (32, 64, 128)  # strides 4, 8, 16
    feat_stride: int = 8  # image features leave the backbone at stride 4 (a third FPN level) or 8
    feat_channels: int = 64  # image context features lifted into BEV
    depth_min_m: float = 1.0
    depth_max_m: float = 45.0
    depth_bins: int = 44
    lift_z_range_m: tuple[float, float] = (-3.0, 2.0)  # lidar-frame heights kept (lidar ~1.84 m up)
    bev_cell_m: float = 0.5
    bev_channels: int = 64
    num_queries: int = 60
    one2many_queries: int = 120  # MapTRv2 hybrid matching: extra training-only queries (0: off)
    one2many_k: int = 3  # ... matched to the GT repeated this many times
    decoder_layers: int = 3
    decoder_dim: int = 128
    decoder_heads: int = 4
    # how much of the vector decoder's gradient reaches the BEV features (0: none, 1: all). Early in
    # training the set loss's gradient (random queries, changing matches) swamps the dense losses
    # that teach the lift where lines are; measured in docs/transfer.md
    decoder_grad_scale: float = 0.0
    decoder_sees_seg: bool = False  # the decoder also samples the BEV segmentation logits (detached)

    def __post_init__(self) -> None:
        _check_positive(
            self,
            (
                "num_points",
                "input_focal_px",
                "stem_channels",
                "feat_channels",
                "depth_min_m",
                "depth_bins",
                "bev_cell_m",
                "bev_channels",
                "num_queries",
                "decoder_layers",
                "decoder_dim",
                "decoder_heads",
            ),
        )
        if not 0.0 <= self.decoder_grad_scale <= 1.0:
            raise ValueError(f"MapModelConfig.decoder_grad_scale {self.decoder_grad_scale} is not in [0, 1]")
        if self.depth_max_m <= self.depth_min_m:
            raise ValueError(f"MapModelConfig.depth_max_m must exceed depth_min_m, got {self.depth_max_m}")
        if self.lift_z_range_m[1] <= self.lift_z_range_m[0]:
            raise ValueError(f"MapModelConfig.lift_z_range_m must be (low, high), got {self.lift_z_range_m}")
        if self.decoder_dim % self.decoder_heads:
            raise ValueError("MapModelConfig.decoder_dim must be a multiple of decoder_heads")
        if not self.classes or len(set(self.classes)) != len(self.classes):
            raise ValueError(f"MapModelConfig.classes must be distinct and non-empty, got {self.classes}")
        if self.feat_stride not in FEAT_STRIDES:
            raise ValueError(f"MapModelConfig.feat_stride must be in {FEAT_STRIDES}, got {self.feat_stride}")
        if self.num_points < 2:
            raise ValueError("MapModelConfig.num_points must be >= 2")

    @property
    def half_extent_xy(self) -> tuple[float, float]:
        """(right, forward) half sizes of the patch: lidar x within +-[0], y within +-[1]."""
        return self.patch[1] / 2.0, self.patch[0] / 2.0

    @property
    def bev_shape(self) -> tuple[int, int]:
        """(rows along lidar y = forward, columns along lidar x = right)."""
        return round(self.patch[0] / self.bev_cell_m), round(self.patch[1] / self.bev_cell_m)


@dataclass(frozen=True)
class LossConfig:
    """MapTR's weights: focal classification 2, normalised point L1 5, edge direction 0.005; plus the
    MapTRv2-style auxiliary dense losses (BEV and perspective-view segmentation of the map lines,
    LiDAR depth of the lift)."""

    cls_weight: float = 2.0
    pts_weight: float = 5.0
    dir_weight: float = 0.005
    bev_seg_weight: float = 1.0
    pv_seg_weight: float = 1.0
    one2many_weight: float = 1.0
    depth_weight: float = 1.0  # LiDAR depth supervision of the lift (cross-entropy over the depth bins)
    focal_alpha: float = 0.25
    focal_gamma: float = 2.0


@dataclass(frozen=True)
class TrainConfig:
    """One training run: steps, optimiser, schedule, evaluation and checkpoint cadence."""

    steps: int = 3000
    batch_size: int = 2
    lr: float = 2e-3
    weight_decay: float = 1e-2
    warmup_steps: int = 100
    grad_clip: float = 5.0
    seed: int = 0
    threads: int = 2
    eval_every: int = 500  # 0: evaluate only at the end
    checkpoint_every: int = 250
    bev_flip: bool = True  # mirror the BEV frame at random (see nuav2.mapping.augment)
    bev_rotate: bool = True  # rotate the BEV frame by one of the data's rotations_deg (or not) at random
    loss: LossConfig = field(default_factory=LossConfig)

    def __post_init__(self) -> None:
        _check_positive(self, ("steps", "batch_size", "lr", "threads"))
        if self.warmup_steps < 0 or self.eval_every < 0 or self.checkpoint_every < 0:
            raise ValueError("TrainConfig: warmup_steps, eval_every and checkpoint_every must be >= 0")


def config_to_dict(cfg) -> dict:
    return asdict(cfg)


def model_config_from_dict(d: dict) -> MapModelConfig:
    known = {f.name for f in fields(MapModelConfig)}
    bad = sorted(set(d) - known)
    if bad:
        raise ValueError(f"unknown MapModelConfig field(s) {bad}")
    tuples = {k: tuple(v) for k, v in d.items() if isinstance(v, list)}
    return MapModelConfig(**{**d, **tuples})


def fingerprint(*parts) -> str:
    """Short stable hash of configs / plain values (dataclasses are hashed by their fields)."""
    norm = [asdict(p) if hasattr(p, "__dataclass_fields__") else p for p in parts]
    return hashlib.sha256(json.dumps(norm, sort_keys=True, default=str).encode()).hexdigest()[:16]
