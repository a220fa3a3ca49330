"""MapTRv2 info ``.pkl`` export: the per-keyframe records MapTRv2's own training code reads.

Fields follow MapTRv2's ``custom_nusc_map_converter`` (see docs/maptr.md): sample links and
time, LIDAR_TOP path and pose, up to 10 previous LIDAR_TOP sweeps, six cameras each with its
own ego pose and its ``sensor2lidar`` transform (p_lidar = R p_cam + t), a zeros(18) CAN bus
with the pose fields MapTR's dataset fills, the map location, and the vectorized GT in the
LIDAR_TOP frame under ``annotation``. Split membership comes from ``<version>/splits.json``
instead of the devkit's hard-coded nuScenes scene lists. ``sample_info`` is shared with the
torch dataset, so both see the same poses.
"""

from __future__ import annotations

import logging
import math
import pickle
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from nuav2.atomic import atomic_write_bytes
from nuav2.geometry import F64, T_from_quat_trans, T_inverse, quat_to_rot, yaw_of
from nuav2.maptr.subsets import available_splits, scene_sample_tokens, split_scene_names
from nuav2.maptr.vectorize import CLASSES, DEFAULT_PATCH, MapGT

log = logging.getLogger(__name__)

NUSCENES_CAMERAS = (
    "CAM_FRONT",
    "CAM_FRONT_RIGHT",
    "CAM_FRONT_LEFT",
    "CAM_BACK",
    "CAM_BACK_LEFT",
    "CAM_BACK_RIGHT",
)
LIDAR_CHANNEL = "LIDAR_TOP"
MAX_SWEEPS = 10
CAN_BUS_SIZE = 18


def info_filename(prefix: str, split: str) -> str:
    return f"{prefix}_map_infos_temporal_{split}.pkl"


def camera_channels(nusc, sample: dict, cameras: Sequence[str] | None = None) -> list[str]:
    """The requested cameras, else nuScenes' six in MapTR's order when all are present, else every
    camera channel of the sample (e.g. AV2's ring in native mode) sorted by name."""
    if cameras is not None:
        missing = [c for c in cameras if c not in sample["data"]]
        if missing:
            raise ValueError(
                f"{nusc.dataroot}/{nusc.version}: sample {sample['token']} lacks cameras {missing}"
            )
        return list(cameras)
    if all(c in sample["data"] for c in NUSCENES_CAMERAS):
        return list(NUSCENES_CAMERAS)
    present = []
    for ch, sd_token in sample["data"].items():
        sd = nusc.get("sample_data", sd_token)
        if nusc.get("calibrated_sensor", sd["calibrated_sensor_token"])["camera_intrinsic"]:
            present.append(ch)
    return sorted(present)


def _pose_T(record: dict) -> F64:
    return T_from_quat_trans(record["rotation"], record["translation"])


def can_bus_from_pose(translation: Sequence[float], rotation_wxyz: Sequence[float]) -> F64:
    """zeros(18) with what MapTR's dataset writes into it: [0:3] ego t, [3:7] ego q (wxyz),
    [-2] yaw in rad and [-1] in degrees, both taken in [0, 360) as MapTR does."""
    can_bus = np.zeros(CAN_BUS_SIZE)
    can_bus[:3] = translation
    can_bus[3:7] = rotation_wxyz
    yaw_deg = math.degrees(yaw_of(quat_to_rot(rotation_wxyz)))
    if yaw_deg < 0:
        yaw_deg += 360.0
    can_bus[-2] = yaw_deg / 180.0 * math.pi
    can_bus[-1] = yaw_deg
    return can_bus


def _sensor_info(nusc, sd_token: str, lidar_T_global: F64, path_root: str, kind: str) -> dict:
    """One sensor reading in MapTR's layout, with its own ego pose and its pose in the key LIDAR_TOP frame."""
    sd = nusc.get("sample_data", sd_token)
    cs = nusc.get("calibrated_sensor", sd["calibrated_sensor_token"])
    ego = nusc.get("ego_pose", sd["ego_pose_token"])
    lidar_T_sensor = lidar_T_global @ _pose_T(ego) @ _pose_T(cs)
    info = {
        "data_path": _data_path(nusc, path_root, sd["filename"]),
        "type": kind,
        "sample_data_token": sd_token,
        "sensor2ego_translation": list(cs["translation"]),
        "sensor2ego_rotation": list(cs["rotation"]),
        "ego2global_translation": list(ego["translation"]),
        "ego2global_rotation": list(ego["rotation"]),
        "timestamp": sd["timestamp"],
        "sensor2lidar_rotation": lidar_T_sensor[:3, :3].copy(),
        "sensor2lidar_translation": lidar_T_sensor[:3, 3].copy(),
    }
    if cs["camera_intrinsic"]:
        info["cam_intrinsic"] = np.asarray(cs["camera_intrinsic"], dtype=np.float64)
        info["width"], info["height"] = sd.get("width"), sd.get("height")
    return info


def _data_path(nusc, path_root: str, filename: str) -> str:
    """Where the file is, written under ``path_root`` (the dataroot by default) as MapTR expects."""
    disk = Path(nusc.dataroot) / filename
    if not disk.is_file():
        raise FileNotFoundError(
            f"{disk}: referenced by sample_data in {nusc.dataroot}/{nusc.version} but missing"
        )
    return str(Path(path_root) / filename) if path_root else str(disk)


def sample_info(
    nusc,
    sample_token: str,
    frame_idx: int,
    max_sweeps: int = MAX_SWEEPS,
    cameras: Sequence[str] | None = None,
    path_root: str = "",
) -> dict:
    """MapTRv2 info record of one keyframe, without ``annotation``."""
    sample = nusc.get("sample", sample_token)
    if LIDAR_CHANNEL not in sample["data"]:
        raise ValueError(f"{nusc.dataroot}/{nusc.version}: sample {sample_token} has no {LIDAR_CHANNEL}")
    lidar_sd = nusc.get("sample_data", sample["data"][LIDAR_CHANNEL])
    lidar_cs = nusc.get("calibrated_sensor", lidar_sd["calibrated_sensor_token"])
    lidar_ego = nusc.get("ego_pose", lidar_sd["ego_pose_token"])
    lidar_T_global = T_inverse(_pose_T(lidar_ego) @ _pose_T(lidar_cs))
    scene = nusc.get("scene", sample["scene_token"])
    info = {
        "lidar_path": _data_path(nusc, path_root, lidar_sd["filename"]),
        "token": sample_token,
        "prev": sample["prev"],
        "next": sample["next"],
        "can_bus": can_bus_from_pose(lidar_ego["translation"], lidar_ego["rotation"]),
        "frame_idx": frame_idx,
        "sweeps": [],
        "cams": {},
        "scene_token": sample["scene_token"],
        "lidar2ego_translation": list(lidar_cs["translation"]),
        "lidar2ego_rotation": list(lidar_cs["rotation"]),
        "ego2global_translation": list(lidar_ego["translation"]),
        "ego2global_rotation": list(lidar_ego["rotation"]),
        "timestamp": sample["timestamp"],
        "map_location": nusc.get("log", scene["log_token"])["location"],
    }
    sd = lidar_sd
    while len(info["sweeps"]) < max_sweeps and sd["prev"]:
        info["sweeps"].append(_sensor_info(nusc, sd["prev"], lidar_T_global, path_root, "lidar"))
        sd = nusc.get("sample_data", sd["prev"])
    for ch in camera_channels(nusc, sample, cameras):
        info["cams"][ch] = _sensor_info(nusc, sample["data"][ch], lidar_T_global, path_root, ch)
    return info


def lidar2img(cam_info: dict) -> F64:
    """4x4 LIDAR_TOP -> pixel projection K4 [R | -R T], R = inv(sensor2lidar_rotation), as MapTR builds it
    (the inverse of a rotation is its transpose)."""
    R = np.asarray(cam_info["sensor2lidar_rotation"], dtype=np.float64).T
    T = np.asarray(cam_info["sensor2lidar_translation"], dtype=np.float64)
    cam_T_lidar = np.eye(4)
    cam_T_lidar[:3, :3] = R
    cam_T_lidar[:3, 3] = -R @ T
    K4 = np.eye(4)
    K4[:3, :3] = np.asarray(cam_info["cam_intrinsic"], dtype=np.float64)
    return K4 @ cam_T_lidar


def annotation_of(vectors: list[tuple[str, F64]]) -> dict[str, list[F64]]:
    """MapTR's ``annotation`` dict: every class key present, lists of (N, 2) lidar-frame polylines."""
    ann: dict[str, list[F64]] = {cls: [] for cls in CLASSES}
    for cls, pts in vectors:
        ann[cls].append(np.asarray(pts, dtype=np.float64))
    return ann


def split_infos(
    nusc,
    split: str,
    gt: MapGT | None = None,
    max_sweeps: int = MAX_SWEEPS,
    cameras: Sequence[str] | None = None,
    path_root: str = "",
    progress: bool = True,
) -> list[dict]:
    """Info records of every keyframe of ``split``, scene by scene in time order."""
    from nuav2.progress import progress_bar

    gt = gt or MapGT(nusc.dataroot)
    jobs = [
        (tok, i)
        for name in split_scene_names(nusc, split)
        for i, tok in enumerate(scene_sample_tokens(nusc, name))
    ]
    infos = []
    for tok, frame_idx in progress_bar(jobs, desc=f"infos {split}", unit="sample", disable=not progress):
        info = sample_info(nusc, tok, frame_idx, max_sweeps, cameras, path_root)
        info["annotation"] = annotation_of(gt.sample_vectors(nusc, tok))
        infos.append(info)
    return infos


def scenes_stay_contiguous_by_time(infos: list[dict]) -> bool:
    """MMDet3D sorts infos by timestamp; MapTR's temporal queue breaks if that interleaves scenes."""
    order = sorted(infos, key=lambda e: e["timestamp"])
    seen, last = set(), None
    for info in order:
        s = info["scene_token"]
        if s != last:
            if s in seen:
                return False
            seen.add(s)
            last = s
    return True


def export_infos(
    dataroot: str | Path,
    version: str,
    out_dir: str | Path,
    prefix: str = "nuav2",
    splits: Sequence[str] | None = None,
    max_sweeps: int = MAX_SWEEPS,
    patch: tuple[float, float] = DEFAULT_PATCH,
    path_root: str = "",
    cameras: Sequence[str] | None = None,
) -> dict[str, Path]:
    """Write ``{prefix}_map_infos_temporal_{split}.pkl`` per split (default: all in splits.json)."""
    from nuscenes.nuscenes import NuScenes

    nusc = NuScenes(version=version, dataroot=str(dataroot), verbose=False)
    splits = list(splits) if splits else available_splits(nusc)
    gt = MapGT(dataroot, patch)
    written: dict[str, Path] = {}
    for split in splits:
        infos = split_infos(nusc, split, gt, max_sweeps, cameras, path_root)
        if not scenes_stay_contiguous_by_time(infos):
            log.warning(
                "split %s: sorting by timestamp (as MMDet3D does) interleaves scenes; "
                "MapTR's temporal queue will see scene changes mid-sequence",
                split,
            )
        path = Path(out_dir) / info_filename(prefix, split)
        atomic_write_bytes(
            path,
            pickle.dumps(
                {"infos": infos, "metadata": {"version": version}}, protocol=pickle.HIGHEST_PROTOCOL
            ),
        )
        log.info("wrote %s (%d samples)", path, len(infos))
        written[split] = path
    return written
