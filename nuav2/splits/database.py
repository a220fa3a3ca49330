"""The database side of splitting: scene positions in true city coordinates, existing splits,
and writing ``splits.json`` next to the tables."""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from nuav2.atomic import atomic_write_json
from nuav2.nuscenes_db.map_frame import LOCATION_RE, city_offset_of
from nuav2.nuscenes_db.merge import LOGS_FILE
from nuav2.splits.geo import leakage_counts
from nuav2.splits.names import DISCARDED, GEO_PREFIX, LEAKAGE_RADIUS_M, SPLIT_PREFIXES, SPLITS
from nuav2.splits.regions import read_json_lists


@dataclass
class SceneTable:
    """What the splitter needs from a database: where each scene's samples are, in which city."""

    positions: dict[str, np.ndarray]  # scene name -> (N, 2) true city xy of its LIDAR_TOP keyframes
    city_of: dict[str, str]
    identifiers: dict[str, set[str]]  # scene name -> name, token, log token, log file, description


def _nuav2_logs(dataroot: Path, version: str) -> dict[str, dict]:
    """The converter's ``<version>/nuav2_logs.json`` (a list of per-log records), keyed by log token
    and by location; empty if the file is absent (a database nuav2 did not write)."""
    path = dataroot / version / LOGS_FILE
    if not path.is_file():
        return {}
    try:
        records = json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise ValueError(f"{path}: cannot read the per-log city placement ({e})") from None
    if not isinstance(records, list) or not all(isinstance(r, dict) for r in records):
        raise ValueError(f"{path}: expected a JSON list of per-log records, as nuav2 convert writes")
    out: dict[str, dict] = {}
    for r in records:
        for key in (r.get("log_token"), r.get("location")):
            if isinstance(key, str) and key:
                out[key] = r
    return out


def log_city_placement(dataroot: Path, version: str, log_rec: dict, cache: dict) -> tuple[str, np.ndarray]:
    """(city, city_offset[:2]) of a converted AV2 log: ``nuav2_logs.json`` first, else the expansion JSON
    (a ValueError naming the file if neither is readable; ``cache`` is shared over a database's logs)."""
    location = log_rec["location"]
    if "sidecar" not in cache:
        cache["sidecar"] = _nuav2_logs(dataroot, version)
    for key in (log_rec["token"], location):
        rec = cache["sidecar"].get(key)
        if rec is not None:
            where = f"{dataroot / version / LOGS_FILE} (log {rec.get('log_id', key)})"
            return str(rec["city"]), city_offset_of(rec, where)[:2]
    if location not in cache:
        path = dataroot / "maps" / "expansion" / f"{location}.json"
        try:
            meta = json.loads(path.read_text())["nuav2"]
            cache[location] = (str(meta["city_name"]), city_offset_of(meta, str(path))[:2])
        except (OSError, ValueError, KeyError, TypeError) as e:
            raise ValueError(
                f"{path}: cannot read the 'nuav2' city placement of location {location} "
                f"({type(e).__name__}: {e}); without it nuAV2 scenes cannot be placed in "
                f"city coordinates"
            ) from None
    return cache[location]


def read_scene_table(dataroot: str | Path, version: str) -> SceneTable:
    """Scene sample positions in true city coordinates from a nuScenes-format database (devkit)."""
    from nuscenes.nuscenes import NuScenes

    dataroot = Path(dataroot)
    nusc = NuScenes(version=version, dataroot=str(dataroot), verbose=False)
    names = [s["name"] for s in nusc.scene]
    if any(not n for n in names) or len(set(names)) != len(names):
        raise ValueError(
            f"{dataroot}/{version}/scene.json: scene names must be unique and non-empty "
            f"(splits.json lists scenes by name)"
        )
    cache: dict = {}
    table = SceneTable({}, {}, {})
    for scene in nusc.scene:
        log_rec = nusc.get("log", scene["log_token"])
        if LOCATION_RE.match(log_rec["location"]):
            city, offset = log_city_placement(dataroot, version, log_rec, cache)
        else:
            city, offset = log_rec["location"], np.zeros(2)
        xy, tok = [], scene["first_sample_token"]
        while tok:
            sample = nusc.get("sample", tok)
            if "LIDAR_TOP" not in sample["data"]:
                raise ValueError(
                    f"{dataroot}/{version}: sample {tok} of {scene['name']} has no LIDAR_TOP data"
                )
            pose = nusc.get(
                "ego_pose", nusc.get("sample_data", sample["data"]["LIDAR_TOP"])["ego_pose_token"]
            )
            xy.append(pose["translation"][:2])
            tok = sample["next"]
        pts = np.asarray(xy, dtype=np.float64).reshape(-1, 2) + offset
        if not np.all(np.isfinite(pts)):
            raise ValueError(f"{dataroot}/{version}: scene {scene['name']} has non-finite ego poses")
        table.positions[scene["name"]] = pts
        table.city_of[scene["name"]] = city
        table.identifiers[scene["name"]] = {
            scene["name"],
            scene["token"],
            scene["description"],
            log_rec["token"],
            log_rec["logfile"],
        } - {""}
    return table


def available_splits(dataroot: str | Path, version: str) -> dict[str, list[str]]:
    """{split name: scene names} a consumer can ask for: ``<version>/splits.json`` (which wins on a
    name clash), then each of the devkit's built-in nuScenes lists that has scenes in this database."""
    folder = Path(dataroot) / version
    try:
        present = {s.get("name") for s in json.loads((folder / "scene.json").read_text())}
    except (OSError, ValueError, AttributeError) as e:
        raise ValueError(f"{folder / 'scene.json'}: cannot read the scene table ({e})") from None
    out: dict[str, list[str]] = {}
    from nuscenes.utils.splits import create_splits_scenes

    for name, scenes in create_splits_scenes().items():
        if any(s in present for s in scenes):
            out[name] = [s for s in scenes if s in present]
    out.update(_read_splits_file(folder / "splits.json"))
    return out


def _read_splits_file(path: Path) -> dict[str, list[str]]:
    """``splits.json`` as {split name: [scene names]}; {} when absent, a ValueError naming it when bad."""
    if not path.is_file():
        return {}
    return read_json_lists(path, "splits", "{split name: [scene names]}")


def existing_splits(
    dataroot: str | Path, version: str, scenes: Sequence[str]
) -> dict[str, dict[str, list[str]]]:
    """Splits already defined for this database: ``<version>/splits.json`` and the devkit's lists."""
    present = set(scenes)
    out: dict[str, dict[str, list[str]]] = {}
    data = _read_splits_file(Path(dataroot) / version / "splits.json")
    for prefix in SPLIT_PREFIXES:
        if f"{prefix}train" in data:
            out[f"splits.json:{prefix}*"] = {
                k: [s for s in data.get(f"{prefix}{k}", []) if s in present] for k in SPLITS}
    from nuscenes.utils.splits import create_splits_scenes

    builtin = create_splits_scenes()
    for name, keys in (
        ("devkit", ("train", "val", "test")),
        ("devkit-mini", ("mini_train", "mini_val", None)),
    ):
        split = {k: [s for s in builtin[b] if s in present] if b else [] for k, b in zip(SPLITS, keys)}
        if split["train"] and (split["val"] or split["test"]):
            out[name] = split
    return out


def write_splits(
    dataroot: str | Path, version: str, splits: Mapping[str, Sequence[str]], report: dict
) -> Path:
    """Add ``geo_train/geo_val/geo_test/geo_discarded`` to ``<version>/splits.json`` (other keys, e.g.
    the converter's ``av2_*`` source splits, are kept) and write ``splits_report.json``, atomically.

    The ``geo_`` prefix matters: the devkit resolves ``train``/``val``/``test`` from its own
    hard-coded nuScenes lists and reads only other names from ``splits.json``.
    """
    folder = Path(dataroot) / version
    path = folder / "splits.json"
    merged: dict[str, list[str]] = {}
    if path.is_file():
        try:
            merged = json.loads(path.read_text())
        except (OSError, json.JSONDecodeError) as e:
            raise ValueError(f"{path}: cannot read existing splits ({e})") from None
    for k in (*SPLITS, DISCARDED):
        merged[f"{GEO_PREFIX}{k}"] = list(splits.get(k, []))
    atomic_write_json(path, merged, indent=1)
    atomic_write_json(folder / "splits_report.json", report, indent=1)
    return path


def split_summary(
    splits: Mapping[str, Sequence[str]], table: SceneTable, radius: float = LEAKAGE_RADIUS_M
) -> dict:
    """Scenes and samples per split plus the leakage statistic (share of holdout samples near train)."""
    samples = {k: int(sum(len(table.positions[s]) for s in splits.get(k, []))) for k in (*SPLITS, DISCARDED)}
    return {
        "scenes": {k: len(splits.get(k, [])) for k in (*SPLITS, DISCARDED)},
        "samples": samples,
        "leakage_radius_m": radius,
        "leakage": leakage_counts(splits, table.positions, radius, table.city_of),
    }
