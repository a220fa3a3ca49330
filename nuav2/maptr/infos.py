"""MapTRv2 info ``.pkl`` export: the per-keyframe records MapTRv2's own training code reads.

Fields follow MapTRv2's ``custom_nusc_map_converter`` (see docs/maptr.md): sample links and
time, LIDAR_TOP path and pose, up to 10 previous LIDAR_TOP sweeps, the cameras (a fixed rig order)
each with its own ego pose and its ``sensor2lidar`` transform (p_lidar = R p_cam + t), an
18-value CAN bus (pose, and acceleration / rotation rate / velocity from neighbouring LIDAR_TOP
poses, since AV2 has no CAN bus), the map location, and the vectorized GT in the LIDAR_TOP frame
under ``annotation``. Split membership comes from ``<version>/splits.json``
instead of the devkit's hard-coded nuScenes scene lists. ``sample_info`` is shared with the
torch dataset, so both see the same poses.
"""

from __future__ import annotations

import collections
import contextlib
import itertools
import json
import logging
import math
import os
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np

from nuav2.atomic import atomic_file
from nuav2.ego_motion import ego_motion
from nuav2.geometry import F64, T_from_quat_trans, T_inverse, quat_to_rot, yaw_of
from nuav2.maptr.info_pickle import InfoPickleStream, record_bytes
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
# MapTR's AV2 converter (CAM_NAMES): the ring in this order, stereo left out.
AV2_RING_CAMERAS = (
    "ring_front_center",
    "ring_front_right",
    "ring_front_left",
    "ring_rear_right",
    "ring_rear_left",
    "ring_side_right",
    "ring_side_left",
)
LIDAR_CHANNEL = "LIDAR_TOP"
MAX_SWEEPS = 10
CAN_BUS_SIZE = 18


class MissingCameraError(ValueError):
    """A requested camera channel is not in a sample (the CLI names ``--cameras``)."""


def info_filename(prefix: str, split: str) -> str:
    return f"{prefix}_map_infos_temporal_{split}.pkl"


def camera_sensor_channels(sensor_rows: Sequence[dict]) -> set[str]:
    """The camera channels of a ``sensor`` table."""
    return {row["channel"] for row in sensor_rows if row.get("modality") == "camera"}


def default_cameras(nusc) -> list[str]:
    """The database's camera order, the same for every keyframe (MapTR's per-camera embeddings are
    indexed by position): nuScenes' six in MapTR's order when the sensor table has them, else AV2's
    seven ring cameras in MapTR's AV2 order (stereo left out, as MapTR's AV2 converter does), else
    every camera channel sorted by name."""
    present = camera_sensor_channels(nusc.sensor)
    for rig in (NUSCENES_CAMERAS, AV2_RING_CAMERAS):
        if present.issuperset(rig):
            return list(rig)
    return sorted(present)


def camera_channels(nusc, sample: dict, cameras: Sequence[str] | None = None) -> list[str]:
    """The requested cameras, else :func:`default_cameras`; a keyframe that lacks one is refused
    (a keyframe with fewer or other cameras would shift every camera after the gap)."""
    wanted = list(cameras) if cameras is not None else default_cameras(nusc)
    missing = [c for c in wanted if c not in sample["data"]]
    if missing:
        hint = "" if cameras is not None else " (--cameras picks cameras every keyframe has)"
        raise MissingCameraError(
            f"{nusc.dataroot}/{nusc.version}: sample {sample['token']} lacks camera(s) "
            f"{', '.join(missing)}{hint}"
        )
    return wanted


def _pose_T(record: dict) -> F64:
    return T_from_quat_trans(record["rotation"], record["translation"])


def _require_finite(nusc, table: str, record: dict, *fields: str) -> None:
    """Refuse a record whose numbers are NaN or Inf: they would go into the .pkl as they are (and every
    projection of that camera or sweep with them) without an error."""
    for field in fields:
        values = np.asarray(record[field] if record[field] is not None else [], dtype=np.float64)
        if not np.isfinite(values).all():
            raise ValueError(f"{nusc.dataroot}/{nusc.version}/{table}.json: record {record['token']} has "
                             f"NaN or Inf in '{field}'")


def can_bus_from_pose(
    translation: Sequence[float], rotation_wxyz: Sequence[float], motion: Sequence[float] | None = None
) -> F64:
    """The 18 values in the layout of MapTR's nuScenes converter: [0:3] ego t, [3:7] ego q (wxyz),
    [7:16] ``motion`` (accel, rotation rate, velocity; see :func:`ego_motion`), zeros if None,
    [-2] yaw in rad in [0, 2 pi] and [-1] in degrees in [0, 360], as MapTR's dataset writes them (a yaw a
    hair below 0 gives 360.0 there too)."""
    can_bus = np.zeros(CAN_BUS_SIZE)
    can_bus[:3] = translation
    can_bus[3:7] = rotation_wxyz
    if motion is not None:
        can_bus[7:16] = motion
    yaw_deg = math.degrees(yaw_of(quat_to_rot(rotation_wxyz)))
    if yaw_deg < 0:
        yaw_deg += 360.0
    can_bus[-2] = yaw_deg / 180.0 * math.pi
    can_bus[-1] = yaw_deg
    return can_bus


def _chain_motion(nusc, lidar_sd: dict) -> F64:
    """:func:`ego_motion` of a keyframe's LIDAR_TOP pose from its sample_data chain (10 Hz sweeps):
    its neighbours, or the two next to it on the one side there is; out-of-order times are left out."""
    before = [nusc.get("sample_data", lidar_sd["prev"])] if lidar_sd["prev"] else []
    after = [nusc.get("sample_data", lidar_sd["next"])] if lidar_sd["next"] else []
    if after and not before and after[0]["next"]:
        after.append(nusc.get("sample_data", after[0]["next"]))
    if before and not after and before[0]["prev"]:
        before.append(nusc.get("sample_data", before[0]["prev"]))
    chain = [lidar_sd]
    for sd in before:
        if sd["timestamp"] < chain[0]["timestamp"]:
            chain.insert(0, sd)
    index = len(chain) - 1
    for sd in after:
        if sd["timestamp"] > chain[-1]["timestamp"]:
            chain.append(sd)
    poses = [nusc.get("ego_pose", sd["ego_pose_token"]) for sd in chain]
    global_T_ego = T_from_quat_trans([p["rotation"] for p in poses], [p["translation"] for p in poses])
    return ego_motion([sd["timestamp"] * 1e-6 for sd in chain], global_T_ego, index)


def _sensor_info(nusc, sd_token: str, lidar_T_global: F64, path_root: str, kind: str) -> dict:
    """One sensor reading in MapTR's layout, with its own ego pose and its pose in the key LIDAR_TOP frame."""
    sd = nusc.get("sample_data", sd_token)
    cs = nusc.get("calibrated_sensor", sd["calibrated_sensor_token"])
    ego = nusc.get("ego_pose", sd["ego_pose_token"])
    _require_finite(nusc, "calibrated_sensor", cs, "translation", "rotation", "camera_intrinsic")
    _require_finite(nusc, "ego_pose", ego, "translation", "rotation")
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
    """Where the file is, written under ``path_root`` (the dataroot by default) exactly as given:
    MapTR's own infos hold ``./data/nuscenes/...``, which pathlib would shorten to ``data/...``."""
    disk = os.path.join(nusc.dataroot, filename)
    if not os.path.isfile(disk):
        raise FileNotFoundError(
            f"{disk}: referenced by sample_data in {nusc.dataroot}/{nusc.version} but missing"
        )
    return os.path.join(path_root, filename) if path_root else disk


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
    _require_finite(nusc, "calibrated_sensor", lidar_cs, "translation", "rotation")
    _require_finite(nusc, "ego_pose", lidar_ego, "translation", "rotation")
    lidar_T_global = T_inverse(_pose_T(lidar_ego) @ _pose_T(lidar_cs))
    scene = nusc.get("scene", sample["scene_token"])
    info = {
        "lidar_path": _data_path(nusc, path_root, lidar_sd["filename"]),
        "token": sample_token,
        "prev": sample["prev"],
        "next": sample["next"],
        "can_bus": can_bus_from_pose(lidar_ego["translation"], lidar_ego["rotation"],
                                     _chain_motion(nusc, lidar_sd)),
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


MAX_CACHED_MAPS = 8  # map vectorizers kept per process: nuScenes has 4 locations, nuAV2 one per log


class SceneInfoMaker:
    """The devkit tables and the map GT of one dataroot, turning one scene at a time into pickled
    info records (:func:`nuav2.maptr.info_pickle.record_bytes`). One lives in the main process, or
    in each local worker process or Ray actor; each scene's maps are loaded lazily and at most
    ``MAX_CACHED_MAPS`` stay cached, so memory does not grow with the number of logs."""

    def __init__(self, dataroot: str | Path, version: str, patch: tuple[float, float] = DEFAULT_PATCH,
                 max_sweeps: int = MAX_SWEEPS, cameras: Sequence[str] | None = None, path_root: str = ""):
        from nuscenes.nuscenes import NuScenes

        self.nusc = NuScenes(version=version, dataroot=str(dataroot), verbose=False)
        self.gt = MapGT(dataroot, patch)
        self.max_sweeps, self.cameras, self.path_root = max_sweeps, cameras, path_root

    def scene(self, scene_name: str) -> tuple[bytes, int, list[tuple[str, int]]]:
        """(record bytes of the keyframes in time order, their count, (scene token, timestamp) of each)."""
        parts, times = [], []
        for frame_idx, tok in enumerate(scene_sample_tokens(self.nusc, scene_name)):
            info = sample_info(self.nusc, tok, frame_idx, self.max_sweeps, self.cameras, self.path_root)
            info["annotation"] = annotation_of(self.gt.sample_vectors(self.nusc, tok))
            parts.append(record_bytes(info))
            times.append((info["scene_token"], info["timestamp"]))
        cached = self.gt._by_location  # MapGT's lazy per-location cache, bounded here
        while len(cached) > MAX_CACHED_MAPS:
            cached.pop(next(iter(cached)))
        return b"".join(parts), len(parts), times


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


class _SceneIndex:
    """What split selection and the camera default read of a database (dataroot, version, scene and
    sensor records), without loading the devkit's tables into the main process when workers do the work."""

    def __init__(self, dataroot: str | Path, version: str):
        self.dataroot, self.version = str(dataroot), version
        for name in ("scene", "sensor"):
            path = Path(dataroot) / version / f"{name}.json"
            try:
                setattr(self, name, json.loads(path.read_text()))
            except (OSError, ValueError) as e:
                raise FileNotFoundError(
                    f"{path}: cannot read the {name} table ({type(e).__name__}: {e})"
                ) from e


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
    workers: int = 1,
    executor: str = "local",
    ray_address: str | None = None,
    progress: bool = True,
) -> dict[str, Path]:
    """Write ``{prefix}_map_infos_temporal_{split}.pkl`` per split (default: every split with
    scenes: splits.json's and the version's own nuScenes release lists, ``available_splits``).

    Scenes are turned into records by ``workers`` local processes (or Ray actors with
    ``executor="ray"``) and streamed into each file in split order; the bytes are the same
    whatever the number of workers.
    """
    from nuav2.executors.progress import BatchProgress

    index = _SceneIndex(dataroot, version)
    asked = bool(splits)
    splits = list(splits) if splits else available_splits(index)
    jobs = {split: split_scene_names(index, split) for split in splits}
    empty = [split for split, names in jobs.items() if not names]
    if empty and asked:  # an empty .pkl would load as a dataset of length 0, far from here
        full = [s for s in available_splits(index) if split_scene_names(index, s)]
        raise ValueError(f"split(s) {', '.join(empty)} hold no scenes in {dataroot}/{version}, nothing to "
                         f"export; splits with scenes: {', '.join(full) or 'none'}")
    maker_args = (str(dataroot), version, tuple(patch), max_sweeps,
                  tuple(cameras) if cameras else None, path_root)
    written: dict[str, Path] = {}
    keyframes: set[tuple[str, int]] = set()  # (scene token, timestamp): a keyframe in several splits once
    with scene_runner(maker_args, workers, executor, ray_address) as run_scenes:
        for split, names in jobs.items():
            path = Path(out_dir) / info_filename(prefix, split)
            times: list[dict] = []
            bar = BatchProgress(len(names), enabled=progress, desc=f"infos {split}", unit="scene")
            try:
                with atomic_file(path) as f:
                    stream = InfoPickleStream(f)
                    for records, count, scene_times in run_scenes(names, bar):
                        stream.add(records, count)
                        times += [{"scene_token": s, "timestamp": t} for s, t in scene_times]
                        keyframes.update(scene_times)
                    stream.close({"version": version})
            finally:
                bar.close()
            if not scenes_stay_contiguous_by_time(times):
                log.warning(
                    "split %s: sorting by timestamp (as MMDet3D does) interleaves scenes; "
                    "MapTR's temporal queue will see scene changes mid-sequence",
                    split,
                )
            if stream.count:
                log.info("wrote %s (%d samples)", path, stream.count)
            else:
                log.warning("wrote %s with no samples (split %s: %d scene(s) with keyframes)",
                            path, split, len(names))
            written[split] = path
    if not cameras and not default_cameras(index):  # every keyframe's cams == {}
        log.warning(
            "%s/%s: %d of %d keyframes have no camera (cams == {}): MapTR's image pipeline cannot use "
            "them; convert the logs with their cameras",
            dataroot, version, len(keyframes), len(keyframes),
        )
    return written


@contextlib.contextmanager
def scene_runner(maker_args: tuple, workers: int, executor: str, ray_address: str | None) -> Iterator:
    """A function ``(scene names, progress) -> iterator of SceneInfoMaker.scene results in that order``,
    in this process, in ``workers`` local processes, or in Ray actors."""
    if executor == "ray":
        from nuav2.executors.ray_infos import ray_scene_runner

        with ray_scene_runner(maker_args, workers, ray_address) as run:
            yield run
    elif workers <= 1:
        maker = SceneInfoMaker(*maker_args)

        def run_here(names, bar):
            for name in names:
                bar.update(running=1)
                out = maker.scene(name)
                bar.update(finished=1, running=0)
                yield out

        yield run_here
    else:
        from nuav2.executors.local import worker_pool

        with worker_pool(workers, _init_worker_maker, (maker_args,)) as pool:
            yield lambda names, bar: _ordered(pool, names, workers, bar)


_WORKER_MAKER: SceneInfoMaker | None = None


def _init_worker_maker(maker_args: tuple) -> None:
    global _WORKER_MAKER
    _WORKER_MAKER = SceneInfoMaker(*maker_args)


def _worker_scene(name: str) -> tuple[bytes, int, list]:
    assert _WORKER_MAKER is not None
    return _WORKER_MAKER.scene(name)


def _ordered(pool, names: list[str], workers: int, bar) -> Iterator:
    """Results in ``names`` order with at most 2 x ``workers`` scenes in flight (bounded memory)."""
    window: collections.deque = collections.deque()
    todo = iter(names)
    for name in itertools.islice(todo, 2 * workers):
        window.append(pool.submit(_worker_scene, name))
    while window:
        bar.update(running=min(len(window), workers))
        out = window.popleft().result()
        nxt = next(todo, None)
        if nxt is not None:
            window.append(pool.submit(_worker_scene, nxt))
        bar.update(finished=1)
        yield out
