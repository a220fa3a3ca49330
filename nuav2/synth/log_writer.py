"""Write a synthetic world as an AV2 sensor log that av2's official loaders read.

Layout (``out_dir/<split>/<log_id>/``), schemas and dtypes follow av2_format.md: poses with
one row per sensor timestamp, calibration for the ring cameras (+ stereo if configured) and
both lidars at the chosen image scale, float16 ego-frame lidar sweeps, cuboid annotations
(train/val only) with ``num_interior_pts`` counted from the sweep (exact, or with the
``label_noise`` factor as imperfect as human labels, labels.py), JPEGs at each camera's own
timestamp (the clean render, or with the ``exposure`` factor through each camera's exposure,
white balance, vignetting and noise, camera_effects.py), and the map directory. The log
directory appears atomically (temp dir + rename).
"""

from __future__ import annotations

import contextlib
import io
import json
import time
from pathlib import Path

import cv2
import numpy as np
import pyarrow as pa
import pyarrow.feather as feather

from nuav2.atomic import atomic_directory
from nuav2.geometry import T_inverse, T_to_quat_trans
from nuav2.progress import progress_bar
from nuav2.synth.camera_effects import CAMERA_EFFECTS_FILE, EFFECTS_JPEG_QUALITY, CameraEffects
from nuav2.synth.config import SynthConfig
from nuav2.synth.labels import label_errors
from nuav2.synth.map_json import write_map_dir
from nuav2.synth.raycast import cast_sweep
from nuav2.synth.render import render_view
from nuav2.synth.world import LIDARS, WORLD_FILE, SyntheticWorld, build_world

SPLITS = ("train", "val", "test")
_POSE_COLS = ("qw", "qx", "qy", "qz", "tx_m", "ty_m", "tz_m")


def _write(path: Path, data: bytes) -> None:
    """Plain write: every file goes into the log's temp directory, which is renamed into place
    as a whole (nuav2.atomic.atomic_directory), so per-file temp+fsync would only cost time."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data)


def _write_feather(path: Path, table: pa.Table) -> None:
    buf = io.BytesIO()
    feather.write_feather(table, buf, compression="lz4")  # pyarrow's default, deterministic
    _write(path, buf.getvalue())


def _pose_columns(T: np.ndarray) -> dict[str, pa.Array]:
    q, t = T_to_quat_trans(T.reshape(-1, 4, 4))
    vals = np.column_stack([q, t])
    return {name: pa.array(vals[:, i], pa.float64()) for i, name in enumerate(_POSE_COLS)}


def poses_table(world: SyntheticWorld) -> pa.Table:
    ts = world.timeline.all_sensor_ns()
    return pa.table({"timestamp_ns": pa.array(ts, pa.int64()), **_pose_columns(world.city_T_ego_at(ts))})


def calibration_tables(world: SyntheticWorld) -> tuple[pa.Table, pa.Table]:
    """(egovehicle_SE3_sensor, intrinsics) from the AV2 rig at the log's image scale."""
    rig = world.rig
    cams = [rig.camera(ch) for ch in world.camera_channels]
    names = [c.channel for c in cams] + list(LIDARS)
    ego_T_sensor = np.stack([c.ego_T_cam for c in cams] + [rig.lidar(n).ego_T_lidar for n in LIDARS])
    extr = pa.table({"sensor_name": pa.array(names, pa.string()), **_pose_columns(ego_T_sensor)})
    f64 = pa.float64()
    intr = pa.table({
        "sensor_name": pa.array([c.channel for c in cams], pa.string()),
        "fx_px": pa.array([c.K[0, 0] for c in cams], f64), "fy_px": pa.array([c.K[1, 1] for c in cams], f64),
        "cx_px": pa.array([c.K[0, 2] for c in cams], f64), "cy_px": pa.array([c.K[1, 2] for c in cams], f64),
        "k1": pa.array([0.0] * len(cams), f64), "k2": pa.array([0.0] * len(cams), f64),
        "k3": pa.array([0.0] * len(cams), f64),
        "height_px": pa.array([c.height for c in cams], pa.uint16()),
        "width_px": pa.array([c.width for c in cams], pa.uint16()),
    })
    return extr, intr


def stored_xyz(ret) -> np.ndarray:
    """A sweep's points as AV2 stores them (float16 in the ego frame), widened back to float64."""
    return ret.xyz_ego.astype(np.float16).astype(np.float64)


def sweep_table(ret) -> pa.Table:
    xyz = stored_xyz(ret)
    return pa.table({"x": pa.array(xyz[:, 0], pa.float16()), "y": pa.array(xyz[:, 1], pa.float16()),
                     "z": pa.array(xyz[:, 2], pa.float16()), "intensity": pa.array(ret.intensity, pa.uint8()),
                     "laser_number": pa.array(ret.laser_number, pa.uint8()),
                     "offset_ns": pa.array(ret.offset_ns, pa.int32())})


def interior_counts(xyz_ego: np.ndarray, ego_T_box: np.ndarray, size_lwh: np.ndarray) -> np.ndarray:
    """Points inside each cuboid, faces included (AV2's ``num_interior_pts``). Counted on the
    points as written (float16), not on the ray hits: hits lie on the actor's faces, and rounding
    puts about half of them just outside its box."""
    counts = np.zeros(len(ego_T_box), dtype=np.int64)
    order = np.argsort(xyz_ego[:, 0], kind="stable")
    xs = xyz_ego[order, 0]
    for k, (T, lwh) in enumerate(zip(ego_T_box, size_lwh)):
        reach = 0.5 * float(np.linalg.norm(lwh)) + 1e-6  # the box's bounding sphere, along x
        lo, hi = np.searchsorted(xs, [T[0, 3] - reach, T[0, 3] + reach], side="left")
        local = (xyz_ego[order[lo:hi]] - T[:3, 3]) @ T[:3, :3]
        counts[k] = np.count_nonzero(np.all(np.abs(local) <= 0.5 * lwh, axis=1))
    return counts


def annotation_rows(world: SyntheticWorld, timestamp_ns: int, box_hits: np.ndarray,
                    xyz_written: np.ndarray) -> dict[str, list]:
    """Cuboids of the actors in the ego frame at a sweep; ``box_hits`` are the sweep's solid indices
    (what an annotator sees of each actor), ``xyz_written`` its points as stored (ego frame)."""
    poses = world.actor_poses_at(timestamp_ns)
    ego_T_city = T_inverse(world.city_T_ego_at(timestamp_ns))
    ego_T_box = ego_T_city[None] @ poses.city_T_box
    owner = world.boxes_at(timestamp_ns).owner[box_hits[box_hits >= 0]]
    k = len(poses.track_uuid)
    size = poses.size_lwh
    keep = np.arange(k)
    if world.config.label_noise:  # an actor's ray hits decide whether the annotator missed it
        hits = np.bincount(owner[owner >= 0], minlength=k)[:k].astype(np.int64)
        ego_T_box, size, kept = label_errors(world.seed, poses.track_uuid, timestamp_ns, ego_T_box, size,
                                             hits)
        keep = np.flatnonzero(kept)
    counts = interior_counts(xyz_written, ego_T_box[keep], size[keep])  # in the boxes as labelled
    q, t = T_to_quat_trans(ego_T_box[keep])
    n = len(keep)
    return {"timestamp_ns": [int(timestamp_ns)] * n, "track_uuid": [poses.track_uuid[i] for i in keep],
            "category": [poses.category[i] for i in keep],
            "length_m": size[keep, 0].tolist(), "width_m": size[keep, 1].tolist(),
            "height_m": size[keep, 2].tolist(),
            **{c: v.tolist() for c, v in zip(_POSE_COLS, np.column_stack([q, t]).T)},
            "num_interior_pts": counts.tolist()}


def annotations_table(rows: list[dict[str, list]]) -> pa.Table:
    f64 = pa.float64()
    cols = {k: sum((r[k] for r in rows), []) for k in rows[0]} if rows else {}
    types = {"timestamp_ns": pa.int64(), "track_uuid": pa.string(), "category": pa.string(),
             "length_m": f64, "width_m": f64, "height_m": f64, **{c: f64 for c in _POSE_COLS},
             "num_interior_pts": pa.int64()}
    return pa.table({k: pa.array(cols.get(k, []), t) for k, t in types.items()})


def encode_jpeg(rgb: np.ndarray, quality: int) -> bytes:
    bgr = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2BGR)  # same bytes as a flipped copy, faster
    ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise RuntimeError("JPEG encoding failed")
    return buf.tobytes()


def write_log(world: SyntheticWorld, log_dir: Path, split: str = "train", progress: bool = False) -> dict:
    """Write every file of the log into ``log_dir`` (an empty directory); returns timing stats."""
    cfg = world.config
    tl = world.timeline
    _write(log_dir / WORLD_FILE, json.dumps(world.describe(), indent=1).encode())
    extr, intr = calibration_tables(world)
    _write_feather(log_dir / "calibration" / "egovehicle_SE3_sensor.feather", extr)
    _write_feather(log_dir / "calibration" / "intrinsics.feather", intr)
    _write_feather(log_dir / "city_SE3_egovehicle.feather", poses_table(world))
    write_map_dir(world, log_dir / "map")
    cams = [world.rig.camera(ch) for ch in world.camera_channels]
    effects = CameraEffects(world.seed, world.camera_channels, cfg.camera_noise) if cfg.exposure else None
    noisy = cfg.exposure and cfg.camera_noise
    quality = min(cfg.jpeg_quality, EFFECTS_JPEG_QUALITY) if noisy else cfg.jpeg_quality
    rows = []
    t_start = time.perf_counter()
    n_points = 0
    for k in progress_bar(range(len(tl.sweeps_ns)), desc=f"synth {world.log_id[:8]}", unit="frame",
                          disable=not progress):
        ts = int(tl.sweeps_ns[k])
        ret = cast_sweep(world, ts)
        n_points += len(ret.offset_ns)
        _write_feather(log_dir / "sensors" / "lidar" / f"{ts}.feather", sweep_table(ret))
        rows.append(annotation_rows(world, ts, ret.box, stored_xyz(ret)))
        for cam in cams:
            for img_ts in tl.images_ns[cam.channel][2 * k: 2 * k + 2]:
                city_T_cam = world.city_T_ego_at(int(img_ts)) @ cam.ego_T_cam
                img = render_view(world, cam, city_T_cam, int(img_ts))
                if effects is not None:
                    img = effects.apply(cam, img, float(world.seconds_since_start(int(img_ts))), int(img_ts))
                _write(log_dir / "sensors" / "cameras" / cam.channel / f"{int(img_ts)}.jpg",
                       encode_jpeg(img, quality))
    frames_s = time.perf_counter() - t_start
    if effects is not None:
        _write(log_dir / CAMERA_EFFECTS_FILE, json.dumps(effects.describe(), indent=1).encode())
    if split != "test":  # AV2's test split ships without labels
        _write_feather(log_dir / "annotations.feather", annotations_table(rows))
    n = len(tl.sweeps_ns)
    return {"frames": n, "frame_seconds": frames_s, "mean_points": n_points / n}


def generate_log(out_dir: Path, seed: int = 0, config: SynthConfig | None = None, split: str = "train",
                 progress: bool = False) -> Path:
    """Generate the synthetic log for ``seed`` under ``out_dir/<split>/<log_id>`` and return that path.

    Point ``AV2SensorDataLoader(data_dir=out_dir / split, labels_dir=out_dir / split)`` at it.
    Re-running with the same seed and config rewrites byte-identical files.
    """
    if split not in SPLITS:
        raise ValueError(f"split must be one of {SPLITS}, got {split!r}")
    world = build_world(seed, config)
    log_dir = Path(out_dir) / split / world.log_id
    made = [d for d in log_dir.parents if not d.exists()]  # deepest first
    try:
        with atomic_directory(log_dir) as tmp:
            write_log(world, tmp, split, progress)
    except BaseException:  # an interrupted or failed run leaves no empty folders it made
        for d in made:
            with contextlib.suppress(OSError):
                d.rmdir()
        raise
    return log_dir
