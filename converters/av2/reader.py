"""Argoverse 2 sensor log -> ``SceneLog``: the AV2 reader.

Each part of a log is read by its own small module of this package (``poses``, ``lidar``,
``cameras``, ``annotations``, ``calibration``, ``map_files``; the vector map by ``map``).
This module checks that the parts fit together in time and assembles them.
Every problem with the input is an :class:`AV2LogError` naming the file, or a logged skip.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np

from converters.av2.annotations import read_annotations
from converters.av2.calibration import rig_from_calibration
from converters.av2.cameras import list_camera_frames
from converters.av2.errors import AV2LogError
from converters.av2.lidar import list_sweeps, load_av2_sweep
from converters.av2.logs import split_of
from converters.av2.map_files import city_from_map_dir, read_ground_height
from converters.av2.poses import POSE_FILE, read_pose_table
from converters.av2.sync import DEFAULT_CAMERA_TOLERANCE_NS, synced_sweeps
from nuav2.scene import SceneLog, VectorMap

log = logging.getLogger(__name__)


def _within_poses(items: list, pose_ts: np.ndarray, what: str, where: Path) -> list:
    """Items whose timestamp the pose table covers; the rest are dropped with a log line."""
    keep = [x for x in items if pose_ts[0] <= x.timestamp_ns <= pose_ts[-1]]
    if len(keep) != len(items):
        log.warning("%s: dropped %d of %d %s outside the pose table [%d, %d] of %s", where,
                    len(items) - len(keep), len(items), what, pose_ts[0], pose_ts[-1], POSE_FILE)
    return keep


def _read_vector_map(map_dir: Path) -> VectorMap:
    # Imported here so the rest of the reader (find_logs, inspect) does not depend on the map code.
    from converters.av2.map import vector_map_from_dir

    return vector_map_from_dir(map_dir)


def read_log(log_dir: Path, calibration_dir: Path | None = None, *, require_cameras: bool = True,
             camera_tolerance_ns: int = DEFAULT_CAMERA_TOLERANCE_NS,
             channels: list[str] | None = None) -> SceneLog:
    """Read one AV2 sensor log.

    ``calibration_dir`` overrides the log's own ``calibration/`` (for fragments that ship none).
    ``channels`` restricts the cameras (e.g. the 7 ring cameras). With ``require_cameras`` every
    rig camera must have images and at least one sweep must have all cameras within
    ``camera_tolerance_ns``; sweeps that are not synced stay in ``lidar_sweeps`` (reconstruction
    uses them) and :func:`synced_sweeps` leaves them out of the samples.
    """
    log_dir = Path(os.path.abspath(log_dir))  # `.` and `..` have no name to take the log id from
    if not log_dir.is_dir():
        raise AV2LogError(log_dir, "log directory not found")
    calib_dir = Path(calibration_dir) if calibration_dir is not None else log_dir / "calibration"
    if not calib_dir.is_dir():
        raise AV2LogError(calib_dir, "calibration directory not found "
                                     "(give --calibration DIR for a log that ships none)")
    rig = rig_from_calibration(calib_dir, channels)
    pose_ts, city_T_ego = read_pose_table(log_dir)
    sweeps = _within_poses(list_sweeps(log_dir), pose_ts, "lidar sweeps", log_dir)
    if not sweeps:
        raise AV2LogError(log_dir, f"no lidar sweep lies within the pose table of {POSE_FILE}")
    frames = list_camera_frames(log_dir, rig.camera_channels, require_cameras)
    frames = {ch: _within_poses(f, pose_ts, f"{ch} images", log_dir) for ch, f in frames.items()}
    annotations = read_annotations(log_dir)
    unmatched = np.setdiff1d(np.unique(annotations.timestamp_ns), [s.timestamp_ns for s in sweeps])
    if len(unmatched):
        log.info("%s: %d annotated timestamps have no lidar sweep file", log_dir, len(unmatched))
    map_dir = log_dir / "map"
    city, city_frame = city_from_map_dir(map_dir)
    scene = SceneLog(
        log_id=log_dir.name, source="av2", city=city, city_frame=city_frame, rig=rig,
        pose_timestamps_ns=pose_ts, city_T_ego=city_T_ego, lidar_sweeps=sweeps, camera_frames=frames,
        annotations=annotations, vector_map=_read_vector_map(map_dir),
        ground_height=read_ground_height(map_dir),
        split=split_of(log_dir), load_lidar=load_av2_sweep,
    )
    if any(frames.values()) or require_cameras:
        # Cameras without any image are left out of the output (allowed only without require_cameras),
        # so they do not decide which sweeps are in sync.
        imaged = [ch for ch in rig.camera_channels if frames.get(ch)]
        n_synced = len(synced_sweeps(scene, camera_tolerance_ns, channels=imaged))
        if require_cameras and n_synced == 0:
            raise AV2LogError(log_dir / "sensors" / "cameras",
                              f"no lidar sweep has an image from every camera within "
                              f"{camera_tolerance_ns} ns")
        log.info("%s: %d of %d sweeps have an image from each of the %d cameras with images within %.1f ms",
                 log_dir, n_synced, len(sweeps), len(imaged), camera_tolerance_ns / 1e6)
    return scene
