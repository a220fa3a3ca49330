"""Geo-disjoint train/val/test splits of scenes, and the leakage statistic of any split.

Why: on the standard splits most validation samples lie within a few metres of a training
sample (Lilja et al., CVPR 2024: > 80 % of nuScenes val/test within 5 m), so map models are
scored on places they memorised. Three ways to split, all per scene (``splits.json`` lists
scene names, as the devkit's custom splits and ``nuav2.maptr`` read it):

* :func:`geo_split`: scenes joined by "some sample pair closer than ``min_distance_m``" form
  connected components per city; whole components go to the split furthest below its ratio,
  and when val/test are still short, a spatially compact region is carved out of the largest
  train component, the train scenes touching it being *discarded* rather than leaking.
* :func:`region_split`: hand-drawn val/test polygons per city (Lilja et al.): a scene whose
  samples all lie inside a val (test) polygon goes there, one that straddles a boundary is
  dropped (or kept in train), the rest is train.
* :func:`list_split`: published scene/log lists (e.g. Lilja's AV2 log-id lists).

Positions are true city coordinates: different cities never leak. For nuScenes the city is
``log.location`` and positions are global; for nuAV2 logs (locations ``av2-<city>-<id>``) the
global frame is the AV2 city frame minus ``city_offset`` (``nuav2.nuscenes_db.map_frame``),
read from ``<version>/nuav2_logs.json`` if present, else from the ``nuav2`` block of the
location's ``maps/expansion/<location>.json``.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import shapely
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from nuav2.atomic import atomic_write_json
from nuav2.nuscenes_db.map_frame import LOCATION_RE, city_offset_of
from nuav2.nuscenes_db.merge import LOGS_FILE

log = logging.getLogger(__name__)

SPLITS = ("train", "val", "test")
HOLDOUT = ("val", "test")
DISCARDED = "discarded"
GEO_PREFIX = "geo_"  # names this splitter writes into splits.json
# Key prefixes of split groups in splits.json: plain, ours, and the converter's AV2 source splits.
SPLIT_PREFIXES = ("", GEO_PREFIX, "av2_")
LEAKAGE_RADIUS_M = 5.0

Positions = Mapping[str, np.ndarray]  # scene name -> (N, 2) city xy of its samples


# ----------------------------------------------------------------------------------------------
# Leakage
# ----------------------------------------------------------------------------------------------


def _city_groups(scenes: Sequence[str], city_of: Mapping[str, str] | None) -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    for s in scenes:
        out.setdefault(city_of[s] if city_of is not None else "", []).append(s)
    return out


def _xy(positions: Positions, scenes: Sequence[str]) -> np.ndarray:
    arrs = [np.asarray(positions[s], dtype=np.float64).reshape(-1, 2) for s in scenes]
    return np.concatenate(arrs) if arrs else np.zeros((0, 2))


def leakage_counts(
    splits: Mapping[str, Sequence[str]],
    positions: Positions,
    radius: float = LEAKAGE_RADIUS_M,
    city_of: Mapping[str, str] | None = None,
) -> dict[str, dict]:
    """Per holdout split: samples, how many lie within ``radius`` of a train sample (same city)."""
    train = _city_groups(splits.get("train", []), city_of)
    trees = {c: cKDTree(_xy(positions, ss)) for c, ss in train.items()}
    out = {}
    for split in HOLDOUT:
        n = near = 0
        for city, scenes in _city_groups(splits.get(split, []), city_of).items():
            xy = _xy(positions, scenes)
            n += len(xy)
            if city in trees and len(xy) and trees[city].n:
                dist, _ = trees[city].query(xy, k=1, distance_upper_bound=np.nextafter(radius, np.inf))
                near += int(np.count_nonzero(dist <= radius))
        out[split] = {"samples": n, "within_radius": near, "share": near / n if n else None}
    return out


def leakage(
    splits: Mapping[str, Sequence[str]],
    positions: Positions,
    radius: float = LEAKAGE_RADIUS_M,
    city_of: Mapping[str, str] | None = None,
) -> dict[str, float | None]:
    """Share of val (and test) samples within ``radius`` of a train sample; None for an empty split."""
    return {k: v["share"] for k, v in leakage_counts(splits, positions, radius, city_of).items()}


# ----------------------------------------------------------------------------------------------
# Geo-disjoint splitting
# ----------------------------------------------------------------------------------------------


def scene_adjacency(
    positions: Positions, city_of: Mapping[str, str], min_distance_m: float, scenes: Sequence[str]
) -> list[set[int]]:
    """For each scene (index into ``scenes``), the scenes with a sample within ``min_distance_m``."""
    index = {s: i for i, s in enumerate(scenes)}
    adj: list[set[int]] = [set() for _ in scenes]
    if min_distance_m <= 0:
        return adj
    for _, group in _city_groups(scenes, city_of).items():
        xy = _xy(positions, group)
        owner = np.repeat(
            [index[s] for s in group], [len(np.asarray(positions[s]).reshape(-1, 2)) for s in group]
        )
        pairs = cKDTree(xy).query_pairs(min_distance_m, output_type="ndarray")
        a, b = owner[pairs[:, 0]], owner[pairs[:, 1]]
        keep = a != b
        for i, j in np.unique(np.sort(np.stack([a[keep], b[keep]], 1), axis=1), axis=0):
            adj[i].add(int(j))
            adj[j].add(int(i))
    return adj


def _components(adj: list[set[int]]) -> list[list[int]]:
    n = len(adj)
    rows = [i for i, nb in enumerate(adj) for _ in nb]
    cols = [j for nb in adj for j in nb]
    graph = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    comps: dict[int, list[int]] = {}
    for i, lab in enumerate(labels):
        comps.setdefault(int(lab), []).append(i)
    return list(comps.values())


@dataclass
class _State:
    sizes: np.ndarray
    target: dict[str, float]
    members: dict[str, set[int]] = field(default_factory=lambda: {s: set() for s in (*SPLITS, DISCARDED)})

    def count(self, split: str) -> int:
        return int(sum(self.sizes[i] for i in self.members[split]))

    def deficit(self, split: str) -> float:
        return self.target[split] - self.count(split)


def _carve_region(
    comp: list[int],
    need: float,
    adj: list[set[int]],
    positions: Positions,
    scenes: Sequence[str],
    sizes: np.ndarray,
    rng: np.random.Generator,
) -> tuple[list[int], set[int]]:
    """A spatially compact set of scenes of ``comp`` holding >= ``need`` samples, and its train ring.

    Grows from a peripheral scene (one of the five farthest from the component centroid), adding
    scenes by their nearest-sample distance to the seed, so the ring of touching scenes that must
    be discarded stays short.
    """
    centroids = np.array([np.asarray(positions[scenes[i]]).reshape(-1, 2).mean(axis=0) for i in comp])
    weights = sizes[comp]
    centre = (centroids * weights[:, None]).sum(0) / weights.sum()
    far = np.argsort(-np.linalg.norm(centroids - centre, axis=1), kind="stable")[:5]
    seed_xy = centroids[int(rng.choice(far))]
    reach = np.array(
        [
            np.linalg.norm(np.asarray(positions[scenes[i]]).reshape(-1, 2) - seed_xy, axis=1).min()
            for i in comp
        ]
    )
    region: list[int] = []
    got = 0
    for k in np.argsort(reach, kind="stable"):
        if got >= need:
            break
        region.append(comp[k])
        got += int(sizes[comp[k]])
    members = set(region)
    ring = {j for i in region for j in adj[i] if j not in members}
    return region, ring


def geo_split(
    scene_positions: Positions,
    city_of: Mapping[str, str],
    ratios: Sequence[float] = (0.8, 0.1, 0.1),
    min_distance_m: float = 50.0,
    seed: int = 0,
) -> dict[str, list[str]]:
    """Assign scenes to train/val/test so no val/test sample is within ``min_distance_m`` of train.

    Ratios are by sample count. Returns {"train", "val", "test", "discarded": [scene names]};
    "discarded" holds scenes that touch both train and a holdout region, dropped so nothing leaks.
    """
    ratios = tuple(float(r) for r in ratios)
    if len(ratios) != 3 or min(ratios) < 0 or sum(ratios) <= 0 or not np.all(np.isfinite(ratios)):
        raise ValueError(f"ratios must be 3 non-negative numbers (train, val, test), got {ratios}")
    if not np.isfinite(min_distance_m) or min_distance_m < 0:
        raise ValueError(f"min_distance_m must be >= 0, got {min_distance_m}")
    missing = [s for s in scene_positions if s not in city_of]
    if missing:
        raise ValueError(f"no city for {len(missing)} scene(s), e.g. {missing[:3]}")
    scenes = sorted(scene_positions)
    sizes = np.array([len(np.asarray(scene_positions[s]).reshape(-1, 2)) for s in scenes], dtype=np.int64)
    total = float(sizes.sum())
    target = {s: r / sum(ratios) * total for s, r in zip(SPLITS, ratios)}
    state = _State(sizes, target)
    rng = np.random.default_rng(seed)
    adj = scene_adjacency(scene_positions, city_of, min_distance_m, scenes)
    comps = _components(adj)
    comps = [comps[i] for i in rng.permutation(len(comps))]  # seed decides among equal sizes
    comps.sort(key=lambda c: -int(sizes[c].sum()))
    slack = {s: 0.1 * target[s] for s in SPLITS}
    for comp in comps:
        size = int(sizes[comp].sum())
        order = sorted(SPLITS, key=lambda s: -(state.deficit(s) / target[s]) if target[s] > 0 else np.inf)
        dest = next((s for s in order if target[s] > 0 and size <= state.deficit(s) + slack[s]), "train")
        state.members[dest].update(comp)
    for split in HOLDOUT:  # carve what whole components could not give
        while state.deficit(split) > slack[split]:
            train_comps = [c for c in _components_within(state.members["train"], adj) if len(c) > 1]
            if not train_comps:
                break
            comp = max(train_comps, key=lambda c: (int(sizes[c].sum()), -min(c)))
            region, ring = _carve_region(comp, state.deficit(split), adj, scene_positions, scenes, sizes, rng)
            ring &= state.members["train"]
            state.members["train"] -= set(region) | ring
            state.members[split].update(region)
            state.members[DISCARDED].update(ring)
    out = {k: sorted(scenes[i] for i in v) for k, v in state.members.items()}
    _assert_disjoint(out, scene_positions, city_of, min_distance_m)
    return out


def _components_within(members: set[int], adj: list[set[int]]) -> list[list[int]]:
    """Connected components of the sub-graph induced by ``members`` (deterministic order)."""
    seen: set[int] = set()
    comps = []
    for start in sorted(members):
        if start in seen:
            continue
        stack, comp = [start], []
        seen.add(start)
        while stack:
            i = stack.pop()
            comp.append(i)
            for j in adj[i]:
                if j in members and j not in seen:
                    seen.add(j)
                    stack.append(j)
        comps.append(sorted(comp))
    return comps


def _assert_disjoint(
    splits: Mapping[str, Sequence[str]],
    positions: Positions,
    city_of: Mapping[str, str],
    min_distance_m: float,
) -> None:
    if min_distance_m <= 0:
        return
    counts = leakage_counts(splits, positions, min_distance_m, city_of)
    bad = {k: v["within_radius"] for k, v in counts.items() if v["within_radius"]}
    if bad:
        raise RuntimeError(f"geo split leaks: holdout samples within {min_distance_m} m of train: {bad}")


# ----------------------------------------------------------------------------------------------
# Region polygons and published lists
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Region:
    """A val or test polygon in a city's coordinates."""

    city: str
    split: str
    polygon: shapely.Polygon


def region_split(
    scene_positions: Positions, city_of: Mapping[str, str], regions: Sequence[Region], straddle: str = "drop"
) -> dict[str, list[str]]:
    """Lilja-style split: all samples inside a val (test) polygon -> val (test), else train.

    A scene with samples both inside and outside the holdout polygons is dropped to
    "discarded" (``straddle="drop"``) or kept in train (``straddle="train"``).
    """
    if straddle not in ("drop", "train"):
        raise ValueError(f"straddle must be 'drop' or 'train', got {straddle!r}")
    for r in regions:
        if r.split not in HOLDOUT:
            raise ValueError(f"region split must be 'val' or 'test', got {r.split!r}")
    union = {}
    for city in {r.city for r in regions}:
        for split in HOLDOUT:
            polys = [r.polygon for r in regions if r.city == city and r.split == split]
            if polys:
                union[(city, split)] = shapely.unary_union(polys)
                shapely.prepare(union[(city, split)])
    out: dict[str, list[str]] = {k: [] for k in (*SPLITS, DISCARDED)}
    for scene in sorted(scene_positions):
        xy = np.asarray(scene_positions[scene], dtype=np.float64).reshape(-1, 2)
        inside = {}
        for split in HOLDOUT:
            geom = union.get((city_of[scene], split))
            # intersects_xy: inside or on the boundary
            inside[split] = (
                shapely.intersects_xy(geom, xy[:, 0], xy[:, 1])
                if geom is not None
                else np.zeros(len(xy), dtype=bool)
            )
        if len(xy) and inside["val"].all():
            out["val"].append(scene)
        elif len(xy) and inside["test"].all():
            out["test"].append(scene)
        elif inside["val"].any() or inside["test"].any():
            out[DISCARDED if straddle == "drop" else "train"].append(scene)
        else:
            out["train"].append(scene)
    return out


def list_split(
    identifiers: Mapping[str, set[str]], lists: Mapping[str, Sequence[str]]
) -> tuple[dict, list[str]]:
    """Splits from published lists whose entries name scenes by any identifier (name, token, log id).

    ``identifiers``: scene name -> every string that names it. Returns the splits (unlisted
    scenes in "discarded") and the list entries that matched no scene.
    """
    unknown_keys = [k for k in lists if k not in SPLITS]
    if unknown_keys:
        raise ValueError(f"lists may only hold {SPLITS}, got {unknown_keys}")
    owner: dict[str, str] = {}
    for scene, ids in identifiers.items():
        for ident in ids:
            owner.setdefault(ident, scene)
    out: dict[str, list[str]] = {k: [] for k in (*SPLITS, DISCARDED)}
    where: dict[str, str] = {}
    unmatched = []
    for split in SPLITS:
        for entry in lists.get(split, []):
            scene = owner.get(entry)
            if scene is None:
                unmatched.append(entry)
                continue
            if where.get(scene, split) != split:
                raise ValueError(f"scene {scene} is listed in both {where[scene]} and {split}")
            if scene not in where:
                where[scene] = split
                out[split].append(scene)
    out[DISCARDED] = sorted(s for s in identifiers if s not in where)
    return {k: sorted(v) for k, v in out.items()}, unmatched


def load_regions(path: str | Path) -> tuple[list[Region], str]:
    """``{"straddle": "drop"|"train", "regions": [{"city", "split", "polygon": [[x, y], ...]}]}``."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise ValueError(f"{path}: cannot read regions ({e})") from None
    items = data.get("regions") if isinstance(data, dict) else data
    if not isinstance(items, list):
        raise ValueError(f"{path}: expected {{'regions': [{{city, split, polygon}}]}}")
    regions = []
    for i, r in enumerate(items):
        try:
            poly = shapely.Polygon(np.asarray(r["polygon"], dtype=np.float64))
            region = Region(str(r["city"]), str(r["split"]), poly)
        except (KeyError, TypeError, ValueError) as e:
            raise ValueError(
                f"{path}: region {i} needs city, split and polygon [[x, y], ...] ({e})"
            ) from None
        if region.split not in HOLDOUT:
            raise ValueError(f"{path}: region {i} split must be 'val' or 'test', got {region.split!r}")
        if not poly.is_valid or poly.area <= 0:
            raise ValueError(f"{path}: region {i} polygon is invalid ({shapely.is_valid_reason(poly)})")
        regions.append(region)
    straddle = data.get("straddle", "drop") if isinstance(data, dict) else "drop"
    return regions, straddle


def _read_json_lists(path: Path, what: str, expected: str) -> dict[str, list]:
    """A JSON object of lists (``expected`` describes it in the error), a ValueError naming ``path``."""
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise ValueError(f"{path}: cannot read {what} ({e})") from None
    if not isinstance(data, dict) or not all(isinstance(v, list) for v in data.values()):
        raise ValueError(f"{path}: expected {expected}")
    return data


def load_lists(path: str | Path) -> dict[str, list[str]]:
    """``{"train": [...], "val": [...], "test": [...]}`` of scene names, tokens or log ids."""
    data = _read_json_lists(Path(path), "lists", "{split: [scene names, tokens or log ids]}")
    return {k: [str(x) for x in v] for k, v in data.items()}


# ----------------------------------------------------------------------------------------------
# Dataroot side
# ----------------------------------------------------------------------------------------------


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


def _nuav2_placement(dataroot: Path, version: str, log_rec: dict, cache: dict) -> tuple[str, np.ndarray]:
    """(city, city_offset[:2]) of a converted AV2 log: ``nuav2_logs.json`` first, else the expansion JSON."""
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
            city, offset = _nuav2_placement(dataroot, version, log_rec, cache)
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
    return _read_json_lists(path, "splits", "{split name: [scene names]}")


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
