"""Merge per-log shards into the final ``<dataroot>/<version>/`` tables.

Tables are streamed shard by shard (a full AV2 split at 10 Hz samples has ~10M annotations,
too many to hold as Python dicts), in scene-name order, so the bytes depend only on the
shards and the names. The version directory is built beside the old one and swapped in by a
rename: a killed merge leaves the previous database (or none), never a half-written one.
"""

from __future__ import annotations

import json
import logging
import shutil
from collections.abc import Iterable
from pathlib import Path

from nuav2.atomic import atomic_directory
from nuav2.nuscenes_db import shards as sh
from nuav2.nuscenes_db.can_bus import lidar_pose_messages, write_pose_file
from nuav2.nuscenes_db.tables import (
    PER_LOG_TABLES,
    TABLE_NAMES,
    attribute_table,
    category_table,
    sensor_table,
    visibility_table,
)

SPLITS_FILE = "splits.json"
SPLITS_REPORT_FILE = "splits_report.json"  # written by `nuav2 split` beside its geo_* keys
LOGS_FILE = "nuav2_logs.json"  # per-log facts the tables have no field for (city offset, source split)
ALL_SPLIT = "all"


def split_key(source: str, split: str) -> str:
    """Name of a source split in ``splits.json``: prefixed, because the devkit reserves ``train``/``val``
    /``test`` for nuScenes' own scene lists (and then asserts the version ends in ``trainval``)."""
    return f"{source}_{split or 'unsplit'}"


def _write_records(path: Path, chunks: Iterable[list[dict]]) -> int:
    """Write a JSON list from chunks of records without holding them all; returns the count."""
    n = 0
    with open(path, "w", encoding="utf-8") as f:
        f.write("[")
        for records in chunks:
            for r in records:
                f.write(("" if n == 0 else ", ") + json.dumps(r, ensure_ascii=False))
                n += 1
        f.write("]")
    return n


def merge_shards(dataroot: Path, version: str, shard_paths: dict[str, Path],
                 scene_names: dict[str, str]) -> dict[str, int]:
    """Write each scene's CAN bus pose messages (``can_bus.py``), then the 13 tables + ``splits.json`` +
    ``nuav2_logs.json``; returns record counts per table.

    ``shard_paths`` maps log id -> complete shard directory; ``scene_names`` gives each log's
    ``scene-NNNN`` name and fixes the order.
    """
    if not shard_paths:
        raise ValueError("nothing to merge: no log was converted")
    missing = sorted(set(shard_paths) - set(scene_names))
    if missing:
        raise ValueError(f"no scene name for log(s) {missing}")
    order = sorted(shard_paths, key=lambda log_id: (scene_names[log_id], log_id))
    metas = {log_id: sh.read_meta(shard_paths[log_id]) for log_id in order}

    channels: dict[str, str] = {}
    for log_id, meta in metas.items():
        for ch, modality in meta["channels"].items():
            if channels.setdefault(ch, modality) != modality:
                raise ValueError(f"channel {ch!r} is a {channels[ch]} elsewhere but a {modality} in {log_id}")

    def per_log(table: str) -> Iterable[list[dict]]:
        for log_id in order:
            records = sh.read_table(shard_paths[log_id], table)
            if table == "scene":
                for r in records:
                    r["name"] = scene_names[log_id]
            yield records

    counts: dict[str, int] = {}
    dataroot = Path(dataroot)
    shared = {"category": category_table(), "attribute": attribute_table(),
              "visibility": visibility_table(), "sensor": sensor_table(channels)}
    # The CAN bus files first: a merge killed after them leaves the previous tables, whose scenes keep
    # their names (barring scene_names.py's rare hash collision) and so get the same files again.
    lidar_sensors = {r["token"] for r in shared["sensor"] if r["modality"] == "lidar"}
    for log_id in order:
        calib = sh.read_table(shard_paths[log_id], "calibrated_sensor")
        lidar_calib = {r["token"] for r in calib if r["sensor_token"] in lidar_sensors}
        messages = lidar_pose_messages(sh.read_table(shard_paths[log_id], "sample_data"),
                                       sh.read_table(shard_paths[log_id], "ego_pose"), lidar_calib)
        write_pose_file(dataroot, scene_names[log_id], messages)
    with atomic_directory(dataroot / version) as tmp:
        for table in TABLE_NAMES:
            chunks = [shared[table]] if table in shared else per_log(table)
            counts[table] = _write_records(tmp / f"{table}.json", chunks)
        assert set(PER_LOG_TABLES) | set(shared) == set(TABLE_NAMES)

        splits: dict[str, list[str]] = {}
        for log_id in order:
            m = metas[log_id]["meta"]
            splits.setdefault(split_key(m["source"], m["split"]), []).append(scene_names[log_id])
        splits[ALL_SPLIT] = [scene_names[log_id] for log_id in order]
        sources = {metas[log_id]["meta"]["source"] for log_id in order}
        carried, keep_report = _carried_splits(dataroot / version, splits, sources)
        splits.update(carried)
        (tmp / SPLITS_FILE).write_text(json.dumps(splits, indent=1))
        if keep_report:
            shutil.copyfile(dataroot / version / SPLITS_REPORT_FILE, tmp / SPLITS_REPORT_FILE)
        logs = [{**metas[log_id]["meta"], "scene_name": scene_names[log_id]} for log_id in order]
        (tmp / LOGS_FILE).write_text(json.dumps(logs, indent=1, ensure_ascii=False))
    return counts


def _carried_splits(folder: Path, splits: dict[str, list[str]], sources: set[str]) -> tuple[dict, bool]:
    """The keys other tools added to the old ``splits.json`` (``nuav2 split``'s ``geo_*``, a user's own),
    kept when every scene they name is still in the database, and whether ``splits_report.json`` still
    describes them (nothing dropped, the same scenes). A rerun or an added log rebuilds the folder, and
    used to drop them silently: loaders and ``eval`` then fell back to other splits."""
    try:
        old = json.loads((folder / SPLITS_FILE).read_text())
    except (OSError, ValueError):
        return {}, False
    if not isinstance(old, dict):
        return {}, False
    ours = {ALL_SPLIT, *splits}
    present = set(splits[ALL_SPLIT])
    log = logging.getLogger(__name__)
    carried, dropped = {}, []
    for key, scenes in old.items():
        if key in ours or any(key.startswith(f"{source}_") for source in sources):
            continue
        if _scene_list(scenes) and set(scenes) <= present:
            carried[key] = scenes
        else:
            dropped.append(key)
    if dropped:
        log.warning("%s: dropped split(s) %s, which name scenes no longer in the database; rerun "
                    "`nuav2 split`", folder / SPLITS_FILE, ", ".join(dropped))
    same_scenes = _scene_list(old.get(ALL_SPLIT)) and set(old[ALL_SPLIT]) == present
    if carried and not same_scenes:
        log.warning("%s: kept split(s) %s, but the database's scenes changed (new scenes are in none of "
                    "them); rerun `nuav2 split` to assign them", folder / SPLITS_FILE, ", ".join(carried))
    keep_report = bool(carried) and not dropped and same_scenes and (folder / SPLITS_REPORT_FILE).is_file()
    return carried, keep_report


def _scene_list(value) -> bool:
    """Whether a ``splits.json`` value is a list of scene names (a user may have written anything)."""
    return isinstance(value, list) and all(isinstance(v, str) for v in value)
