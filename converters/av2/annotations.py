"""Cuboid annotations of an AV2 log, read with pyarrow because av2's CuboidList drops ``track_uuid``."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from converters.av2.errors import AV2LogError
from converters.av2.feather import read_columns, require_finite
from nuav2.scene import Annotations

log = logging.getLogger(__name__)

ANNOTATIONS_FILE = "annotations.feather"
FLOAT_COLUMNS = ("length_m", "width_m", "height_m", "qw", "qx", "qy", "qz", "tx_m", "ty_m", "tz_m")
COLUMNS = ("timestamp_ns", "track_uuid", "category", *FLOAT_COLUMNS, "num_interior_pts")


def read_annotations(log_dir: Path) -> Annotations:
    """All cuboids of the log, in file order; a log without the file (test split) gets none (logged)."""
    path = log_dir / ANNOTATIONS_FILE
    if not path.exists():
        log.info("%s: no annotations file (test split?); the log gets no boxes", path)
        return Annotations.empty()
    cols = read_columns(path, COLUMNS)
    require_finite(path, cols, FLOAT_COLUMNS)
    size_lwh = np.column_stack([cols[k] for k in ("length_m", "width_m", "height_m")]).astype(np.float64)
    if np.any(size_lwh < 0):
        row = int(np.flatnonzero((size_lwh < 0).any(axis=1))[0])
        raise AV2LogError(path, f"negative box size {size_lwh[row].tolist()} at row {row}")
    q = np.column_stack([cols[k] for k in ("qw", "qx", "qy", "qz")]).astype(np.float64)
    norms = np.linalg.norm(q, axis=1)
    if np.any(norms < 1e-6):
        raise AV2LogError(path, f"zero quaternion at row {int(np.flatnonzero(norms < 1e-6)[0])}")
    q = q / norms[:, None]
    q = np.where(q[:, :1] < 0, -q, q)
    return Annotations(
        timestamp_ns=np.asarray(cols["timestamp_ns"], dtype=np.int64),
        track_id=np.asarray(cols["track_uuid"], dtype=object).astype(str).astype(object),
        category=np.asarray(cols["category"], dtype=object).astype(str).astype(object),
        size_lwh=size_lwh,
        ego_q_box=q,
        ego_t_box=np.column_stack([cols[k] for k in ("tx_m", "ty_m", "tz_m")]).astype(np.float64),
        num_interior_pts=np.asarray(cols["num_interior_pts"], dtype=np.int64),
    )
