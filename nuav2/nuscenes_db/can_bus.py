"""nuScenes' CAN bus expansion for converted logs: ``<dataroot>/can_bus/scene-NNNN_pose.json``.

Why: the stock converters of BEVFormer and MapTR (``create_data.py ... --canbus DIR``) open
``NuScenesCanBus(dataroot=DIR)``, which stops at once when ``DIR/can_bus`` does not exist, and
then read each scene's ``pose`` messages for the 18 ``can_bus`` values their temporal models use.
AV2 has no CAN bus, so each scene gets pose messages derived from its LIDAR_TOP ego poses (one per
sweep, 10 Hz; nuScenes logs them at 50 Hz): ``utime`` (µs), ``pos`` (global, as the ego pose),
``orientation`` (wxyz), and ``accel`` (specific force, gravity included), ``rotation_rate`` and
``vel`` in the ego frame, from :func:`nuav2.ego_motion.ego_motion` on the neighbouring sweeps,
the values ``nuav2 infos`` puts into ``can_bus[7:16]``. Only ``pose`` is written; the other message
types (``ms_imu``, ``steeranglefeedback``, ...) and the derived ``meta``/``route`` are not.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from nuav2.atomic import atomic_write_json
from nuav2.ego_motion import ego_motion
from nuav2.geometry import F64, T_from_quat_trans

CAN_BUS_DIRNAME = "can_bus"


def pose_messages(times_us: np.ndarray, translations: F64, rotations_wxyz: F64) -> list[dict]:
    """One nuScenes CAN ``pose`` message per ego pose (times strictly increasing), keys in the devkit
    files' order; ``pos`` and ``orientation`` are the poses' own values."""
    times_us = np.asarray(times_us, dtype=np.int64)
    global_T_ego = T_from_quat_trans(rotations_wxyz, translations).reshape(-1, 4, 4)
    times_s = times_us.astype(np.float64) * 1e-6
    messages = []
    for i in range(len(times_us)):
        motion = ego_motion(times_s, global_T_ego, i)
        messages.append({"accel": [float(v) for v in motion[0:3]],
                         "orientation": [float(v) for v in rotations_wxyz[i]],
                         "pos": [float(v) for v in translations[i]],
                         "rotation_rate": [float(v) for v in motion[3:6]],
                         "utime": int(times_us[i]),
                         "vel": [float(v) for v in motion[6:9]]})
    return messages


def lidar_pose_messages(sample_data: list[dict], ego_pose: list[dict],
                        lidar_calib_tokens: set[str]) -> list[dict]:
    """A log's pose messages from its tables: the ego poses of its LIDAR_TOP readings in time order
    (a time seen twice is kept once)."""
    pose_of = {p["token"]: p for p in ego_pose}
    readings = sorted((sd for sd in sample_data if sd["calibrated_sensor_token"] in lidar_calib_tokens),
                      key=lambda sd: sd["timestamp"])
    kept, last = [], None
    for sd in readings:
        if sd["timestamp"] != last:
            kept.append(pose_of[sd["ego_pose_token"]])
            last = sd["timestamp"]
    if not kept:
        return []
    return pose_messages(np.array([p["timestamp"] for p in kept]), np.array([p["translation"] for p in kept]),
                         np.array([p["rotation"] for p in kept]))


def write_pose_file(dataroot: Path, scene_name: str, messages: list[dict]) -> Path:
    """``<dataroot>/can_bus/<scene_name>_pose.json``, written atomically."""
    path = Path(dataroot) / CAN_BUS_DIRNAME / f"{scene_name}_pose.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_json(path, messages)
    return path
