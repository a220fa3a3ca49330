"""AV2 cuboid tracks -> nuScenes instances and sample annotations at the samples.

Boxes arrive in the source ego frame at their sweep time; nuScenes wants them in the global
frame, with a nuScenes category, a motion attribute, a LiDAR point count and prev/next links
per instance. Motion is measured on the whole track (every annotated sweep, not just the
samples) so a box's attribute does not depend on the keyframe rate.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nuav2.geometry import F64, make_T, quat_to_rot, rot_to_quat
from nuav2.nuscenes_db.categories import UNKNOWN_VISIBILITY, attribute_for, category_rule, moving_threshold
from nuav2.nuscenes_db.tables import attribute_token, category_token
from nuav2.nuscenes_db.tokens import make_token
from nuav2.nuscenes_db.visibility import visibility_token
from nuav2.scene import Annotations, SceneLog

SPEED_HALF_WINDOW_NS = 500_000_000  # speed = displacement over about +-0.5 s


@dataclass(frozen=True)
class KeyBoxes:
    """The boxes written as sample annotations, sorted by (track, time)."""

    rows: np.ndarray  # (K,) indices into the log's Annotations
    sample_index: np.ndarray  # (K,) sample each box belongs to
    track_id: np.ndarray  # (K,) object
    category: list[str]  # (K,) nuScenes category (the track's)
    attribute: list[str | None]  # (K,)
    global_T_box: F64  # (K, 4, 4)
    ego_T_box: F64  # (K, 4, 4) source ego frame at the sweep
    size_lwh: F64  # (K, 3)
    num_lidar_pts: np.ndarray  # (K,) int64, own copy; -1 = unknown, the writer counts it in the sweep
    visible: np.ndarray  # (K,) float64 visible fraction in the output cameras; NaN = no camera written

    def __len__(self) -> int:
        return len(self.rows)


def _track_category(ann: Annotations, rows: np.ndarray) -> str:
    """The AV2 category a track has most often (ties: alphabetical), so a track keeps one class."""
    names, counts = np.unique(ann.category[rows].astype(str), return_counts=True)
    return str(names[np.argmax(counts)])


def _speeds(ts: np.ndarray, xy: F64) -> F64:
    """Horizontal speed of one time-sorted track at each row over a +-0.5 s window (0 if alone)."""
    lo = np.searchsorted(ts, ts - SPEED_HALF_WINDOW_NS, side="left")
    hi = np.searchsorted(ts, ts + SPEED_HALF_WINDOW_NS, side="right") - 1
    dt = (ts[hi] - ts[lo]).astype(np.float64) * 1e-9
    dist = np.linalg.norm(xy[hi] - xy[lo], axis=1)
    return np.where(dt > 0, dist / np.where(dt > 0, dt, 1.0), 0.0)


def key_boxes(scene: SceneLog, key_ns: np.ndarray, global_T_city: F64) -> KeyBoxes:
    """Geometry, class and attribute of every box annotated at a sample time."""
    ann = scene.annotations
    for name, arr, width in (("size_lwh", ann.size_lwh, 3), ("ego_q_box", ann.ego_q_box, 4),
                             ("ego_t_box", ann.ego_t_box, 3)):
        arr = np.asarray(arr, dtype=np.float64)
        if arr.shape != (len(ann), width) or not np.all(np.isfinite(arr)):
            raise ValueError(f"log {scene.log_id}: annotation {name} must be finite (N, {width})")
    if len(ann) and np.any(np.asarray(ann.size_lwh) <= 0):
        raise ValueError(f"log {scene.log_id}: annotation sizes must be > 0")
    keep = np.array([category_rule(str(c)).nuscenes is not None for c in ann.category], dtype=bool)
    ts_all = np.asarray(ann.timestamp_ns, dtype=np.int64)
    p_ts = scene.pose_timestamps_ns
    slack = scene.max_pose_extrapolation_ns
    keep &= (ts_all >= p_ts[0] - slack) & (ts_all <= p_ts[-1] + slack)
    rows_all = np.flatnonzero(keep)
    empty = KeyBoxes(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, object), [], [],
                     np.zeros((0, 4, 4)), np.zeros((0, 4, 4)), np.zeros((0, 3)), np.zeros(0, np.int64),
                     np.zeros(0))
    if len(rows_all) == 0:
        return empty

    # City pose of every kept box (one pose interpolation per distinct time).
    uniq_ts, inv = np.unique(ts_all[rows_all], return_inverse=True)
    city_T_ego = scene.city_T_ego_at(uniq_ts).reshape(-1, 4, 4)[inv]
    ego_T_box = make_T(quat_to_rot(ann.ego_q_box[rows_all]), ann.ego_t_box[rows_all])
    city_T_box = city_T_ego @ ego_T_box

    key_lookup = {int(t): i for i, t in enumerate(np.asarray(key_ns, dtype=np.int64))}
    tracks = ann.track_id[rows_all].astype(str)
    order = np.lexsort((ts_all[rows_all], tracks))
    out_pos: list[int] = []
    out_cat: list[str] = []
    out_attr: list[str | None] = []
    start = 0
    while start < len(order):
        stop = start
        while stop < len(order) and tracks[order[stop]] == tracks[order[start]]:
            stop += 1
        idx = order[start:stop]
        av2_cat = _track_category(ann, rows_all[idx])
        speeds = _speeds(ts_all[rows_all[idx]], city_T_box[idx, :2, 3])
        ever_moves = bool(np.max(speeds) > moving_threshold(av2_cat))
        nus_cat = category_rule(av2_cat).nuscenes
        assert nus_cat is not None
        for j, speed in zip(idx, speeds):
            if int(ts_all[rows_all[j]]) in key_lookup:
                out_pos.append(int(j))
                out_cat.append(nus_cat)
                out_attr.append(attribute_for(av2_cat, float(speed), ever_moves))
        start = stop
    if not out_pos:
        return empty
    pos = np.asarray(out_pos, dtype=np.int64)
    rows = rows_all[pos]
    return KeyBoxes(
        rows=rows,
        sample_index=np.array([key_lookup[int(t)] for t in ts_all[rows]], dtype=np.int64),
        track_id=tracks[pos].astype(object),
        category=out_cat,
        attribute=out_attr,
        global_T_box=np.asarray(global_T_city) @ city_T_box[pos],
        ego_T_box=ego_T_box[pos],
        size_lwh=np.asarray(ann.size_lwh, dtype=np.float64)[rows],
        num_lidar_pts=np.asarray(ann.num_interior_pts, dtype=np.int64)[rows],
        visible=np.full(len(rows), np.nan),
    )


def count_points_in_boxes(xyz_ego: F64, ego_T_box: F64, size_lwh: F64) -> np.ndarray:
    """Number of points inside each box (faces inclusive); points and boxes in the same frame."""
    xyz = np.asarray(xyz_ego, dtype=np.float64).reshape(-1, 3)
    xyz = xyz[np.all(np.isfinite(xyz), axis=1)]
    counts = np.zeros(len(ego_T_box), dtype=np.int64)
    for k, (T, lwh) in enumerate(zip(np.asarray(ego_T_box), np.asarray(size_lwh))):
        half = 0.5 * np.asarray(lwh, dtype=np.float64)
        near = np.sum((xyz - T[:3, 3]) ** 2, axis=1) <= float(np.sum(half ** 2)) * (1 + 1e-9)
        local = (xyz[near] - T[:3, 3]) @ T[:3, :3]
        counts[k] = int(np.count_nonzero(np.all(np.abs(local) <= half, axis=1)))
    return counts


def annotation_records(log_id: str, boxes: KeyBoxes,
                       sample_tokens: list[str]) -> tuple[list[dict], list[dict]]:
    """(instance records, sample_annotation records) with prev/next linked per instance."""
    if np.any(boxes.num_lidar_pts < 0):
        raise ValueError(f"log {log_id}: LiDAR point counts were not filled in before writing annotations")
    ann_tokens = [make_token(log_id, "sample_annotation", f"{tr}@{sample_tokens[s]}")
                  for tr, s in zip(boxes.track_id, boxes.sample_index)]
    if len(set(ann_tokens)) != len(ann_tokens):
        first: dict[str, int] = {}
        for k, tok in enumerate(ann_tokens):
            if tok in first:
                rows = (int(boxes.rows[first[tok]]), int(boxes.rows[k]))
                sample = sample_tokens[int(boxes.sample_index[k])]
                raise ValueError(f"log {log_id}: track {boxes.track_id[k]!r} has two boxes (annotation rows "
                                 f"{rows[0]} and {rows[1]}) at sample {sample}; "
                                 "they would be two sample_annotation records with one token")
            first[tok] = k
    q_wxyz = rot_to_quat(boxes.global_T_box[:, :3, :3]) if len(boxes) else np.zeros((0, 4))
    instances: list[dict] = []
    anns: list[dict] = []
    i = 0
    while i < len(boxes):
        j = i
        while j < len(boxes) and boxes.track_id[j] == boxes.track_id[i]:
            j += 1
        inst_token = make_token(log_id, "instance", str(boxes.track_id[i]))
        instances.append({"token": inst_token, "category_token": category_token(boxes.category[i]),
                          "nbr_annotations": j - i, "first_annotation_token": ann_tokens[i],
                          "last_annotation_token": ann_tokens[j - 1]})
        for k in range(i, j):
            l, w, h = (float(v) for v in boxes.size_lwh[k])
            attr = boxes.attribute[k]
            anns.append({
                "token": ann_tokens[k],
                "sample_token": sample_tokens[int(boxes.sample_index[k])],
                "instance_token": inst_token,
                "visibility_token": (UNKNOWN_VISIBILITY if np.isnan(boxes.visible[k])
                                     else visibility_token(float(boxes.visible[k]))),
                "attribute_tokens": [attribute_token(attr)] if attr else [],
                "translation": [float(v) for v in boxes.global_T_box[k, :3, 3]],
                "size": [w, l, h],
                "rotation": [float(v) for v in q_wxyz[k]],
                "prev": ann_tokens[k - 1] if k > i else "",
                "next": ann_tokens[k + 1] if k + 1 < j else "",
                "num_lidar_pts": int(boxes.num_lidar_pts[k]),
                "num_radar_pts": 0,
            })
        i = j
    return instances, anns
