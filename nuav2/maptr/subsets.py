"""Which keyframes a run trains on: split scenes, scene-level fraction subsets, equivalent epochs.

Splits come from ``<dataroot>/<version>/splits.json`` (nuAV2 and geo-disjoint splits) before the
devkit's hard-coded nuScenes scene lists, so MapTR-style training is not tied to them.

Equivalent epoch (MapGS paper, "less data" study): training on a fraction of the data needs
more epochs to reach the same number of iterations; one *equivalent epoch* on a subset is the
number of epochs whose iteration count matches one epoch on the full set, i.e. epochs scaled
by ``full_size / subset_size``. The paper rounds this to 1 / fraction (20, 10 and 4 epochs for
5 %, 10 % and 25 %); :func:`equivalent_epoch_factor` uses the true keyframe counts, because a
scene-level subset rarely holds exactly that fraction of the keyframes.
"""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)

PAPER_FRACTIONS = (0.05, 0.10, 0.25)


def _splits_json(nusc) -> Path:
    return Path(nusc.dataroot) / nusc.version / "splits.json"


# The devkit's built-in lists of each nuScenes release, by the version's ending. create_splits_scenes()
# holds every release's lists, and a release's scenes stand in another's lists too (each v1.0-mini
# scene is in trainval's train or val), so a list of another release only looks present.
RELEASE_SPLITS = {
    "-trainval": ("train", "val", "train_detect", "train_track"),
    "-test": ("test",),
    "-mini": ("mini_train", "mini_val"),
}


def release_splits(dataroot: str | Path, version: str) -> dict[str, list[str]]:
    """{split name: scene names} a consumer picks from by default: ``nuav2.splits.available_splits``
    (splits.json, then each devkit list with scenes present) less the devkit's lists of another
    release than ``version``'s (v1.0-mini keeps mini_train/mini_val, not val); a version without
    a release ending keeps every list, and a name splits.json defines is always kept."""
    from nuscenes.utils.splits import create_splits_scenes

    from nuav2.splits import available_splits as splits_present

    splits = splits_present(dataroot, version)
    own = next((names for end, names in RELEASE_SPLITS.items() if version.endswith(end)), None)
    if own is None:
        return splits
    path = Path(dataroot) / version / "splits.json"
    defined = _read_splits(path) if path.is_file() else {}
    foreign = set(create_splits_scenes()) - set(own) - set(defined)
    return {name: scenes for name, scenes in splits.items() if name not in foreign}


def available_splits(nusc) -> list[str]:
    """Split names of this database, sorted (:func:`release_splits`)."""
    return sorted(release_splits(nusc.dataroot, nusc.version))


def _read_splits(path: Path) -> dict[str, list[str]]:
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise ValueError(f"{path}: cannot read splits ({e})") from e
    if not isinstance(data, dict) or not all(
        isinstance(v, list) and all(isinstance(s, str) for s in v) for v in data.values()
    ):
        raise ValueError(f"{path}: splits must be a JSON object {{split name: [scene names]}}")
    return data


def split_scene_names(nusc, split: str) -> list[str]:
    """Scene names of ``split`` that exist in this database, in the split file's order."""
    path = _splits_json(nusc)
    present = {s["name"] for s in nusc.scene}
    if path.is_file() and split in (splits := _read_splits(path)):
        names = splits[split]
        missing = [n for n in names if n not in present]
        if missing:
            raise ValueError(
                f"{path}: split {split!r} names {len(missing)} scene(s) not in the database, "
                f"e.g. {missing[:3]}"
            )
        return list(names)
    from nuscenes.utils.splits import create_splits_scenes

    builtin = create_splits_scenes()
    if split not in builtin:
        where = f"{path}" if path.is_file() else f"{path} (absent)"
        raise ValueError(
            f"unknown split {split!r}: not in {where} nor the devkit's built-in splits {sorted(builtin)}"
        )
    names = [n for n in builtin[split] if n in present]
    if not names:
        raise ValueError(f"{nusc.dataroot}/{nusc.version}: none of the built-in {split!r} scenes is present")
    return names


def scene_sample_tokens(nusc, scene_name: str) -> list[str]:
    """Keyframe tokens of one scene in time order (walks the sample linked list)."""
    scene = next((s for s in nusc.scene if s["name"] == scene_name), None)
    if scene is None:
        raise KeyError(f"{nusc.dataroot}/{nusc.version}: no scene named {scene_name!r}")
    tokens, tok = [], scene["first_sample_token"]
    while tok:
        tokens.append(tok)
        tok = nusc.get("sample", tok)["next"]
    return tokens


def split_sample_tokens(nusc, split: str, scene_names: Sequence[str] | None = None) -> list[str]:
    """Keyframes of ``split`` (or of the given scenes), scene by scene, each in time order."""
    names = split_scene_names(nusc, split) if scene_names is None else list(scene_names)
    return [tok for name in names for tok in scene_sample_tokens(nusc, name)]


def scene_fraction_subset(scene_names: Sequence[str], fraction: float, seed: int = 0) -> list[str]:
    """``round(fraction * n)`` scenes (at least one) drawn with ``seed``, in their original order.

    The draw is a prefix of one seeded permutation of the sorted names, so for one seed the
    subsets are nested (5 % inside 10 % inside 25 %) and independent of the input order.
    """
    if not 0.0 < fraction <= 1.0:
        raise ValueError(f"fraction must be in (0, 1], got {fraction}")
    names = list(scene_names)
    if len(set(names)) != len(names):
        raise ValueError("scene names must be unique")
    if not names:
        return []
    order = np.random.default_rng(seed).permutation(len(names))
    ranked = [sorted(names)[i] for i in order]
    k = min(len(names), max(1, int(round(fraction * len(names)))))
    chosen = set(ranked[:k])
    return [n for n in names if n in chosen]


def equivalent_epoch_factor(full_size: int, subset_size: int) -> float:
    """Epochs on the subset that match the iterations of one epoch on the full set."""
    if full_size <= 0 or subset_size <= 0:
        raise ValueError(f"dataset sizes must be positive, got full={full_size}, subset={subset_size}")
    return full_size / subset_size


def nominal_equivalent_epoch_factor(fraction: float) -> float:
    """The paper's rounded factor 1 / fraction (20, 10, 4 for 5 %, 10 %, 25 %)."""
    if not 0.0 < fraction <= 1.0:
        raise ValueError(f"fraction must be in (0, 1], got {fraction}")
    return 1.0 / fraction


def epochs_for(equivalent_epochs: float, factor: float) -> int:
    """Whole epochs to run on a subset for ``equivalent_epochs`` (rounded up, tolerant of float fuzz)."""
    if equivalent_epochs < 0 or factor <= 0:
        raise ValueError(f"need equivalent_epochs >= 0 and factor > 0, got {equivalent_epochs}, {factor}")
    return int(math.ceil(equivalent_epochs * factor - 1e-9))
