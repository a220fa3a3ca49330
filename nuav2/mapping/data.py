"""A split of a nuScenes-format dataroot as in-memory tensors, read through ``nuav2.maptr``.

Every keyframe comes from :class:`nuav2.maptr.dataset.MapSampleDataset` (images, ``lidar2img``,
fixed-point GT with its ordering variants), resized so the cameras' median focal length is the
model's ``input_focal_px`` (the same angular resolution whatever the rig), and the dense
auxiliary targets are drawn once. Small synthetic splits fit in memory (300 keyframes of six
71x126 images are ~50 MB), so training never decodes a JPEG twice; a cache file keyed by the
database's tables and the config skips even the first decode on a rerun.
"""

from __future__ import annotations

import hashlib
import logging
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from nuav2.atomic import atomic_file
from nuav2.mapping.config import MapModelConfig, fingerprint
from nuav2.mapping.targets import bev_targets, depth_targets, pv_targets

log = logging.getLogger(__name__)

DATA_FORMAT = 3  # bump when what is cached changes


@dataclass
class MapTensors:
    """Keyframes of one split: model inputs, set targets and dense targets, aligned by index."""

    tokens: list[str]
    img: torch.Tensor  # (S, N, 3, H, W) uint8, zero-padded right/bottom
    img_hw: torch.Tensor  # (S, N, 2) real (H, W) of each image
    lidar2img: torch.Tensor  # (S, N, 4, 4) float32, for the resized pixels
    gt_labels: list[torch.Tensor]  # per sample (G,) int64
    gt_shifts: list[torch.Tensor]  # per sample (G, V, P, 2) float32, LIDAR_TOP metres, padded variants
    bev_target: torch.Tensor  # (S, K, rows, cols) uint8
    pv_target: torch.Tensor  # (S, N, K, h, w) uint8
    depth_target: torch.Tensor  # (S, N, h, w) int16 LiDAR depth bin per feature pixel, -1: none
    meta: dict = field(default_factory=dict)
    # per sample, per angle of meta["rotations_deg"]: that rotated frame's GT (nuav2.mapping.rotations)
    rotated: list[list[dict]] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.tokens)

    def batch(self, index: list[int]) -> dict:
        return {
            "img": self.img[index],
            "img_hw": self.img_hw[index],
            "lidar2img": self.lidar2img[index],
            "gt_labels": [self.gt_labels[i] for i in index],
            "gt_shifts": [self.gt_shifts[i] for i in index],
            "bev_target": self.bev_target[index],
            "pv_target": self.pv_target[index],
            "depth_target": self.depth_target[index],
        }


def _tables_key(dataroot: Path, version: str) -> list:
    """What identifies a database's content: a hash of the tables that change with it (by content, not
    mtime: a resumed conversion or a rerun of ``nuav2 split`` rewrites them unchanged)."""
    out = []
    for name in ("sample_data.json", "sample.json", "calibrated_sensor.json", "splits.json"):
        p = dataroot / version / name
        out.append([name, hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else None])
    return out


def _lidar_points(dataset, index: int) -> np.ndarray:
    """The keyframe's LIDAR_TOP sweep (N, 3), from the file its MapTR info record names (as MapTRv2's
    depth supervision reads it), through the devkit's own reader."""
    from nuscenes.utils.data_classes import LidarPointCloud

    return LidarPointCloud.from_file(dataset.info(index)["lidar_path"]).points[:3].T


def image_scale_for(dataset, cfg: MapModelConfig) -> float:
    """Resize factor giving the cameras' median focal length ``cfg.input_focal_px``."""
    if len(dataset) == 0:
        raise ValueError(f"{dataset.dataroot}/{dataset.version}: the split has no keyframes")
    fx = dataset[0]["cam_intrinsic"][:, 0, 0].double().median().item()
    if not fx > 0:
        raise ValueError(f"{dataset.dataroot}/{dataset.version}: camera focal length {fx} is not positive")
    return cfg.input_focal_px / fx


def load_map_tensors(
    dataroot: str | Path,
    version: str,
    split: str,
    cfg: MapModelConfig,
    *,
    fraction: float | None = None,
    seed: int = 0,
    cache_dir: str | Path | None = None,
    rotations_deg: tuple[float, ...] = (),
) -> MapTensors:
    """Read ``split`` (optionally a seeded scene-level ``fraction``) of a dataroot into tensors.

    ``rotations_deg``: also the GT of every keyframe in its LIDAR_TOP frame rotated by each of these
    angles (a training set's rotation augmentation, :mod:`nuav2.mapping.rotations`).
    """
    from nuav2.mapping.rotations import rotated_targets
    from nuav2.maptr.dataset import MapSampleDataset

    dataroot = Path(dataroot)
    key = fingerprint(
        DATA_FORMAT,
        str(dataroot.resolve()),
        version,
        split,
        fraction,
        seed,
        cfg.classes,
        cfg.num_points,
        list(cfg.patch),
        cfg.input_focal_px,
        cfg.feat_stride,
        cfg.bev_cell_m,
        [cfg.depth_min_m, cfg.depth_max_m, cfg.depth_bins],
        [float(a) for a in rotations_deg],
        _tables_key(dataroot, version),
    )
    cache = Path(cache_dir) / f"maptensors-{key}.pt" if cache_dir else None
    if cache is not None and cache.is_file():
        try:
            data = torch.load(cache, weights_only=False)
            if isinstance(data, MapTensors):
                return data
        except Exception as e:  # noqa: BLE001 - a damaged cache is rebuilt
            log.warning("%s: unreadable cache (%s); rebuilding", cache, e)
    common = dict(
        fraction=fraction, seed=seed, num_points=cfg.num_points, patch=tuple(cfg.patch), classes=cfg.classes
    )
    probe = MapSampleDataset(dataroot, version, split, load_images=False, **common)
    scale = image_scale_for(probe, cfg)
    ds = MapSampleDataset(dataroot, version, split, image_scale=scale, nusc=probe.nusc, **common)
    items = [ds[i] for i in range(len(ds))]
    n_cam = {it["img"].shape[0] for it in items}
    if len(n_cam) != 1:
        raise ValueError(
            f"{dataroot}/{version} {split}: keyframes have different camera counts {sorted(n_cam)}"
        )
    H = max(it["img"].shape[2] for it in items)
    W = max(it["img"].shape[3] for it in items)
    img = torch.zeros((len(items), n_cam.pop(), 3, H, W), dtype=torch.uint8)
    for i, it in enumerate(items):
        img[i, :, :, : it["img"].shape[2], : it["img"].shape[3]] = it["img"]
    feat_hw = (math.ceil(H / cfg.feat_stride), math.ceil(W / cfg.feat_stride))
    data = MapTensors(
        tokens=[it["sample_token"] for it in items],
        img=img,
        img_hw=torch.stack([it["img_shape"] for it in items]),
        lidar2img=torch.stack([it["lidar2img"] for it in items]),
        gt_labels=[it["gt_labels"] for it in items],
        gt_shifts=[it["gt_shifts_pts"] for it in items],
        bev_target=torch.from_numpy(np.stack([bev_targets(it["gt_vectors"], cfg) for it in items])),
        pv_target=torch.from_numpy(
            np.stack(
                [
                    pv_targets(
                        it["gt_vectors"],
                        it["lidar2img"].double().numpy(),
                        it["lidar2ego"].numpy(),
                        feat_hw,
                        cfg,
                    )
                    for it in items
                ]
            )
        ),
        depth_target=torch.from_numpy(
            np.stack(
                [
                    depth_targets(
                        _lidar_points(ds, i),
                        it["lidar2img"].double().numpy(),
                        it["img_shape"].numpy(),
                        feat_hw,
                        cfg,
                    )
                    for i, it in enumerate(items)
                ]
            )
        ),
        meta={
            "dataroot": str(dataroot),
            "version": version,
            "split": split,
            "fraction": fraction,
            "seed": seed,
            "image_scale": scale,
            "scenes": list(ds.scene_names),
            "cameras": items[0]["cam_names"],
            "image_hw": [H, W],
            "rotations_deg": [float(a) for a in rotations_deg],
        },
        rotated=[[rotated_targets(ds, i, a, cfg) for a in rotations_deg] for i in range(len(items))]
        if rotations_deg
        else [],
    )
    if cache is not None:
        with atomic_file(cache) as f:
            torch.save(data, f)
    return data
