"""Builders for the per-log nuScenes records, field by field as nuscenes-devkit 1.2.0 reads them.

Each function returns a plain dict in the field order of the nuScenes schema; the values are
plain Python floats/ints/strings so ``json.dumps`` output is the same in every process.
"""

from __future__ import annotations

from datetime import datetime, timezone

import numpy as np

from nuav2.geometry import F64, T_to_quat_trans
from nuav2.nuscenes_db.tables import sensor_token


def _floats(v) -> list[float]:
    out = [float(x) for x in np.asarray(v, dtype=np.float64).ravel()]
    if not all(np.isfinite(out)):
        raise ValueError(f"non-finite value in a record: {out}")
    return out


def pose_fields(a_T_b: F64) -> tuple[list[float], list[float]]:
    """(translation, rotation wxyz) of a transform, as JSON-ready lists."""
    q, t = T_to_quat_trans(a_T_b)
    return _floats(t), _floats(q)


def ego_pose_record(token: str, global_T_ego: F64, timestamp_us: int) -> dict:
    t, q = pose_fields(global_T_ego)
    return {"token": token, "timestamp": int(timestamp_us), "rotation": q, "translation": t}


def calibrated_sensor_record(token: str, channel: str, ego_T_sensor: F64, K: F64 | None) -> dict:
    """Sensor -> ego extrinsic; ``camera_intrinsic`` is the 3x3 K for cameras, ``[]`` otherwise."""
    t, q = pose_fields(ego_T_sensor)
    intrinsic = [] if K is None else [_floats(row) for row in np.asarray(K, dtype=np.float64)]
    return {"token": token, "sensor_token": sensor_token(channel), "translation": t, "rotation": q,
            "camera_intrinsic": intrinsic}


def sample_record(token: str, timestamp_us: int, scene_token: str, prev: str, next_: str) -> dict:
    return {"token": token, "timestamp": int(timestamp_us), "prev": prev, "next": next_,
            "scene_token": scene_token}


def sample_data_record(token: str, sample_token: str, ego_pose_token: str, calibrated_sensor_token: str,
                       timestamp_us: int, fileformat: str, is_key_frame: bool, height: int, width: int,
                       filename: str, prev: str, next_: str) -> dict:
    return {"token": token, "sample_token": sample_token, "ego_pose_token": ego_pose_token,
            "calibrated_sensor_token": calibrated_sensor_token, "timestamp": int(timestamp_us),
            "fileformat": fileformat, "is_key_frame": bool(is_key_frame), "height": int(height),
            "width": int(width), "filename": filename, "prev": prev, "next": next_}


def scene_record(token: str, log_token: str, nbr_samples: int, first_sample_token: str,
                 last_sample_token: str, name: str, description: str) -> dict:
    return {"token": token, "log_token": log_token, "nbr_samples": int(nbr_samples),
            "first_sample_token": first_sample_token, "last_sample_token": last_sample_token,
            "name": name, "description": description}


def date_captured(timestamp_ns: int) -> str:
    """UTC calendar date of a ns timestamp (AV2's clock is anonymised, so the year is not real)."""
    return datetime.fromtimestamp(int(timestamp_ns) // 1_000_000_000, tz=timezone.utc).strftime("%Y-%m-%d")


def log_record(token: str, logfile: str, vehicle: str, first_timestamp_ns: int, location: str) -> dict:
    return {"token": token, "logfile": logfile, "vehicle": vehicle,
            "date_captured": date_captured(first_timestamp_ns), "location": location}


def map_record(token: str, log_tokens: list[str], filename: str) -> dict:
    return {"category": "semantic_prior", "token": token, "filename": filename,
            "log_tokens": list(log_tokens)}


def linked(tokens: list[str]) -> list[tuple[str, str]]:
    """(prev, next) of each position in a doubly linked list, ``""`` at both ends."""
    return [(tokens[i - 1] if i > 0 else "", tokens[i + 1] if i + 1 < len(tokens) else "")
            for i in range(len(tokens))]
