"""Torch dataset of keyframes for MapTR-style training on any nuScenes-format dataroot.

One item per keyframe: the multi-camera images, ``lidar2img``, ``cam_intrinsic``,
``ego2global`` and ``lidar2ego``, and the map GT (raw polylines plus MapTR's fixed-point
targets with their ordering variants), all from the same ``sample_info`` records the info
export writes. The same class reads nuAV2, AV2-native and real nuScenes dataroots;
:func:`joint_dataset` concatenates several for joint training, and a scene-level fraction
subset with a seed gives the paper's 5/10/25 % runs.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import ConcatDataset, Dataset

from nuav2.geometry import T_from_quat_trans
from nuav2.maptr.fixed_points import fixed_point_targets
from nuav2.maptr.infos import lidar2img, sample_info
from nuav2.maptr.subsets import scene_fraction_subset, scene_sample_tokens, split_scene_names
from nuav2.maptr.vectorize import CLASSES, DEFAULT_PATCH, MapGT

Vectors = list[tuple[str, np.ndarray]]


def load_image_rgb(path: str, scale: float = 1.0) -> np.ndarray:
    """(H, W, 3) uint8 RGB, resized by ``scale``; a missing, undecodable or cut-short file is an error naming
    it (``cv2.imread`` decodes a truncated JPEG with grey rows and only a libjpeg warning on stderr)."""
    import cv2

    from nuav2.image_decode import read_bgr

    img = read_bgr(Path(path))
    if scale != 1.0:
        h, w = img.shape[:2]
        img = cv2.resize(
            img, (max(1, round(w * scale)), max(1, round(h * scale))), interpolation=cv2.INTER_AREA
        )
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


class MapSampleDataset(Dataset):
    """Keyframes of one dataroot (a split, optionally a seeded scene-level fraction of it).

    Images of different sizes (AV2's portrait front camera) are zero-padded at the bottom and
    right to a common size, which leaves the intrinsics valid; ``img_shape`` keeps each real size.
    ``image_scale`` resizes images and scales intrinsics and ``lidar2img`` with them.
    """

    def __init__(
        self,
        dataroot: str | Path,
        version: str,
        split: str,
        *,
        fraction: float | None = None,
        seed: int = 0,
        cameras: Sequence[str] | None = None,
        num_points: int = 20,
        patch: tuple[float, float] = DEFAULT_PATCH,
        classes: Sequence[str] = CLASSES,
        image_scale: float = 1.0,
        load_images: bool = True,
        shift_pattern: str = "resampled",
        nusc=None,
    ):
        from nuscenes.nuscenes import NuScenes

        self.dataroot = Path(dataroot)
        self.version = version
        self.nusc = nusc or NuScenes(version=version, dataroot=str(dataroot), verbose=False)
        scenes = split_scene_names(self.nusc, split)
        if fraction is not None:
            scenes = scene_fraction_subset(scenes, fraction, seed)
        self.scene_names = scenes
        self.items = [
            (tok, i) for name in scenes for i, tok in enumerate(scene_sample_tokens(self.nusc, name))
        ]
        self.cameras = cameras
        self.num_points = num_points
        self.class_ids = {c: i for i, c in enumerate(classes)}
        self.half_extent_xy = (patch[1] / 2.0, patch[0] / 2.0)
        self.image_scale = image_scale
        self.load_images = load_images
        self.shift_pattern = shift_pattern
        self.gt = MapGT(dataroot, patch)

    def __len__(self) -> int:
        return len(self.items)

    def info(self, index: int) -> dict:
        token, frame_idx = self.items[index]
        return sample_info(self.nusc, token, frame_idx, max_sweeps=0, cameras=self.cameras)

    def vectors(self, index: int, lidar_T_patch: np.ndarray | None = None) -> Vectors:
        """GT vectors of keyframe ``index`` (every class), in its LIDAR_TOP frame or one moved from it."""
        return self.gt.sample_vectors(self.nusc, self.items[index][0], lidar_T_patch)

    def fixed_point_targets(
        self, index: int, lidar_T_patch: np.ndarray | None = None
    ) -> tuple[Vectors, np.ndarray, np.ndarray, np.ndarray]:
        """(vectors of this dataset's classes, labels, fixed points, shifts) of keyframe ``index``."""
        vectors = [(c, p) for c, p in self.vectors(index, lidar_T_patch) if c in self.class_ids]
        labels, fixed, shifts = fixed_point_targets(
            vectors,
            self.class_ids,
            self.num_points,
            self.shift_pattern,
            half_extent_xy=self.half_extent_xy,
            rng=np.random.default_rng(index),
        )
        return vectors, labels, fixed, shifts

    def __getitem__(self, index: int) -> dict:
        if not -len(self) <= index < len(self):
            raise IndexError(f"index {index} out of range for {len(self)} samples")
        index %= len(self)
        info = self.info(index)
        cams = list(info["cams"].values())
        S = np.diag([self.image_scale, self.image_scale, 1.0, 1.0])
        intrinsics = np.array([S[:3, :3] @ c["cam_intrinsic"] for c in cams]).reshape(-1, 3, 3)
        projections = np.array([S @ lidar2img(c) for c in cams]).reshape(-1, 4, 4)
        vectors, labels, fixed, shifts = self.fixed_point_targets(index)
        item = {
            "sample_token": info["token"],
            "scene_token": info["scene_token"],
            "frame_idx": info["frame_idx"],
            "timestamp": info["timestamp"],
            "map_location": info["map_location"],
            "cam_names": list(info["cams"]),
            "lidar2img": torch.from_numpy(projections).float(),
            "cam_intrinsic": torch.from_numpy(intrinsics).float(),
            # float64: ego2global carries city-scale translations
            "ego2global": torch.from_numpy(
                T_from_quat_trans(info["ego2global_rotation"], info["ego2global_translation"])
            ),
            "lidar2ego": torch.from_numpy(
                T_from_quat_trans(info["lidar2ego_rotation"], info["lidar2ego_translation"])
            ),
            "gt_labels": torch.from_numpy(labels),
            "gt_pts": torch.from_numpy(fixed).float(),
            "gt_shifts_pts": torch.from_numpy(shifts).float(),
            "gt_vectors": vectors,
        }
        if self.load_images:
            imgs = [load_image_rgb(c["data_path"], self.image_scale) for c in cams]
            H = max((im.shape[0] for im in imgs), default=0)
            W = max((im.shape[1] for im in imgs), default=0)
            batch = np.zeros((len(imgs), 3, H, W), np.uint8)
            for k, im in enumerate(imgs):
                batch[k, :, : im.shape[0], : im.shape[1]] = im.transpose(2, 0, 1)
            item["img"] = torch.from_numpy(batch)
            item["img_shape"] = torch.tensor([im.shape[:2] for im in imgs], dtype=torch.int64).reshape(-1, 2)
        return item


def joint_dataset(datasets: Sequence[MapSampleDataset]) -> ConcatDataset:
    """Several dataroots (e.g. nuAV2 + nuScenes) as one dataset for joint training."""
    if not datasets:
        raise ValueError("joint_dataset needs at least one dataset")
    classes = {tuple(d.class_ids) for d in datasets}
    points = {d.num_points for d in datasets}
    if len(classes) != 1 or len(points) != 1:
        raise ValueError(f"datasets disagree on classes {classes} or points per instance {points}")
    return ConcatDataset(list(datasets))


def collate_map_samples(batch: list[dict]) -> dict:
    """Stack fixed-size fields; keep per-sample lists where sizes differ (GT instances, images)."""
    out: dict = {}
    for key in batch[0]:
        values = [b[key] for b in batch]
        if (
            isinstance(values[0], torch.Tensor)
            and key not in ("gt_labels", "gt_pts", "gt_shifts_pts")
            and all(v.shape == values[0].shape for v in values)
        ):
            out[key] = torch.stack(values)
        else:
            out[key] = values
    return out
