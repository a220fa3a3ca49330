"""Hand-drawn val/test regions (Lilja et al.) and published split lists."""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import shapely

from nuav2.splits.names import DISCARDED, HOLDOUT, SPLITS, Positions


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
    named: dict[str, list[str]] = {}  # a log id names every scene of that log
    for scene, ids in identifiers.items():
        for ident in ids:
            named.setdefault(ident, []).append(scene)
    out: dict[str, list[str]] = {k: [] for k in (*SPLITS, DISCARDED)}
    where: dict[str, str] = {}
    unmatched = []
    for split in SPLITS:
        for entry in lists.get(split, []):
            if entry not in named:
                unmatched.append(entry)
                continue
            for scene in named[entry]:
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


def read_json_lists(path: Path, what: str, expected: str) -> dict[str, list]:
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
    data = read_json_lists(Path(path), "lists", "{split: [scene names, tokens or log ids]}")
    return {k: [str(x) for x in v] for k, v in data.items()}
