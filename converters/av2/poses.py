"""The ego pose table (``city_SE3_egovehicle.feather``, ego -> city) as a strictly increasing series."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from converters.av2.errors import AV2LogError
from converters.av2.feather import INTEGER, NUMBER, read_columns, require_finite
from nuav2.geometry import F64, T_from_quat_trans

log = logging.getLogger(__name__)

POSE_FILE = "city_SE3_egovehicle.feather"
POSE_FLOAT_COLUMNS = ("qw", "qx", "qy", "qz", "tx_m", "ty_m", "tz_m")
POSE_COLUMNS = {"timestamp_ns": INTEGER, **dict.fromkeys(POSE_FLOAT_COLUMNS, NUMBER)}
# Duplicated timestamps whose poses differ by more than this are reported (the first row is kept).
DUPLICATE_POSE_TOL = 1e-6


def read_pose_table(log_dir: Path) -> tuple[np.ndarray, F64]:
    """(timestamps_ns (P,) int64 strictly increasing, city_T_ego (P, 4, 4)).

    Rows are stably sorted by time; a repeated timestamp keeps its first row in file order,
    so the result does not depend on anything but the file.
    """
    path = log_dir / POSE_FILE
    cols = read_columns(path, POSE_COLUMNS)
    require_finite(path, cols, POSE_FLOAT_COLUMNS)
    ts = np.asarray(cols["timestamp_ns"], dtype=np.int64)
    if len(ts) == 0:
        raise AV2LogError(path, "pose table is empty")
    q_wxyz = np.column_stack([cols[k] for k in ("qw", "qx", "qy", "qz")]).astype(np.float64)
    t_xyz = np.column_stack([cols[k] for k in ("tx_m", "ty_m", "tz_m")]).astype(np.float64)
    norms = np.linalg.norm(q_wxyz, axis=1)
    if np.any(norms < 0.5) or np.any(norms > 1.5):
        row = int(np.flatnonzero((norms < 0.5) | (norms > 1.5))[0])
        raise AV2LogError(path, f"quaternion at row {row} has norm {norms[row]:.6g}, expected ~1")
    order = np.argsort(ts, kind="stable")
    ts, q_wxyz, t_xyz = ts[order], q_wxyz[order], t_xyz[order]
    keep = np.ones(len(ts), bool)
    keep[1:] = ts[1:] != ts[:-1]
    n_dup = int((~keep).sum())
    if n_dup:
        first = np.maximum.accumulate(np.where(keep, np.arange(len(ts)), 0))
        diff = np.abs(np.hstack([q_wxyz, t_xyz]) - np.hstack([q_wxyz, t_xyz])[first]).max(axis=1)
        n_conflict = int((diff[~keep] > DUPLICATE_POSE_TOL).sum())
        log.warning("%s: dropped %d rows with a repeated timestamp (%d of them with a different pose); "
                    "kept the first row of each", path, n_dup, n_conflict)
    return ts[keep], T_from_quat_trans(q_wxyz[keep], t_xyz[keep])
