"""Cuboid annotations of an AV2 log, read with pyarrow because av2's CuboidList drops ``track_uuid``."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from converters.av2.errors import AV2LogError
from converters.av2.feather import INTEGER, NUMBER, TEXT, read_columns, require_finite
from converters.av2.logs import split_of
from nuav2.nuscenes_db.categories import AV2_TO_NUSCENES
from nuav2.scene import Annotations

log = logging.getLogger(__name__)

ANNOTATIONS_FILE = "annotations.feather"
LABELLED_SPLITS = ("train", "val")  # AV2 ships boxes with every log of these; test has none
FLOAT_COLUMNS = ("length_m", "width_m", "height_m", "qw", "qx", "qy", "qz", "tx_m", "ty_m", "tz_m")
COLUMNS = {"timestamp_ns": INTEGER, "track_uuid": TEXT, "category": TEXT,
           **dict.fromkeys(FLOAT_COLUMNS, NUMBER), "num_interior_pts": INTEGER}


def _first_repeat(track: np.ndarray, ts: np.ndarray) -> tuple[int, int] | None:
    """(earlier row, later row) of the first (track, timestamp) pair that occurs twice, by the later row."""
    if len(ts) < 2:
        return None
    _, track_code = np.unique(track, return_inverse=True)
    order = np.lexsort((np.arange(len(ts)), ts, track_code))  # by track, then time, then row
    same = (track_code[order[1:]] == track_code[order[:-1]]) & (ts[order[1:]] == ts[order[:-1]])
    if not same.any():
        return None
    k = np.flatnonzero(same)
    k = int(k[np.argmin(order[k + 1])])
    return int(order[k]), int(order[k + 1])


def read_annotations(log_dir: Path) -> Annotations:
    """All cuboids of the log, in file order. A log without the file gets none (logged), unless its
    split is train or val (its folder, else av2's published lists, as the scene records it): there a
    missing file is a partial download, and its scenes would enter a training or validation set
    unlabelled."""
    path = log_dir / ANNOTATIONS_FILE
    if not path.exists():
        split = split_of(Path(log_dir))
        if split in LABELLED_SPLITS:
            raise AV2LogError(path, f"missing; every AV2 {split} log ships its boxes (only test has "
                              f"none): download the log again, or move it to a test/ folder to convert "
                              f"it without boxes")
        log.info("%s: no annotations file (test split?); the log gets no boxes", path)
        return Annotations.empty()
    cols = read_columns(path, COLUMNS)
    require_finite(path, cols, FLOAT_COLUMNS)
    ts = np.asarray(cols["timestamp_ns"], dtype=np.int64)
    track = np.asarray(cols["track_uuid"], dtype=object).astype(str).astype(object)
    category = np.asarray(cols["category"], dtype=object).astype(str).astype(object)
    unknown = ~np.isin(category.astype(str), list(AV2_TO_NUSCENES))
    if unknown.any():
        row = int(np.flatnonzero(unknown)[0])
        raise AV2LogError(path, f"unknown category {category[row]!r} at row {row} (not one of the "
                                f"{len(AV2_TO_NUSCENES)} AV2 categories; {int(unknown.sum())} row(s) in all)")
    size_lwh = np.column_stack([cols[k] for k in ("length_m", "width_m", "height_m")]).astype(np.float64)
    if np.any(size_lwh <= 0):
        row = int(np.flatnonzero((size_lwh <= 0).any(axis=1))[0])
        raise AV2LogError(path, f"box size {size_lwh[row].tolist()} at row {row} is not positive")
    q = np.column_stack([cols[k] for k in ("qw", "qx", "qy", "qz")]).astype(np.float64)
    norms = np.linalg.norm(q, axis=1)
    if np.any(norms < 1e-6):
        raise AV2LogError(path, f"zero quaternion at row {int(np.flatnonzero(norms < 1e-6)[0])}")
    q = q / norms[:, None]
    q = np.where(q[:, :1] < 0, -q, q)
    repeat = _first_repeat(track, ts)
    if repeat is not None:
        a, b = repeat
        raise AV2LogError(path, f"track {track[a]!r} has two boxes at timestamp_ns {ts[a]} (rows {a} and "
                                f"{b}); AV2 annotates each track once per sweep")
    return Annotations(
        timestamp_ns=ts,
        track_id=track,
        category=category,
        size_lwh=size_lwh,
        ego_q_box=q,
        ego_t_box=np.column_stack([cols[k] for k in ("tx_m", "ty_m", "tz_m")]).astype(np.float64),
        num_interior_pts=np.asarray(cols["num_interior_pts"], dtype=np.int64),
    )
