"""``scene.name`` of each converted log: ``scene-NNNN`` outside nuScenes' numbers, stable per log.

Why: NuScenesCanBus asserts ``^scene-\\d{4}$``, and MapTR's and mmdet3d's stock converters
assign scenes to train/val by looking their *names* up in the devkit's nuScenes lists (which
use 0001-1110). So names keep the form but never use those numbers, and a log's name must not
depend on what else is converted with it (joint nuScenes + nuAV2 sets, a second split
converted later into the same OUT).

- AV2 sensor logs: ``2000 + i``, with ``i`` the log's index in av2's published split lists
  ``TRAIN + VAL + TEST`` (``av2.datasets.sensor.splits``, 700 + 150 + 150 logs): 2000-2999.
  Fixed by the log id alone.
- Any other log (synthetic logs, other sources): 3000-9999, at
  ``3000 + int(sha256(log id)[:12], 16) mod 7000``. Two such logs can hash to one number;
  then, over the logs of one database taken in log-id order, a log whose number is taken gets
  the next free number (wrapping from 9999 to 3000). So a name changes only if a log with a
  smaller id and the same hash joins the database; the collision is logged.
"""

from __future__ import annotations

import hashlib
import logging
from collections.abc import Iterable
from functools import lru_cache

log = logging.getLogger(__name__)

AV2_FIRST = 2000
OTHER_FIRST, OTHER_LAST = 3000, 9999
NUSCENES_LAST = 1110  # the devkit's lists use scene-0001 ... scene-1110


class SceneNameError(ValueError):
    """The logs cannot all be given distinct names (duplicate log ids, more logs than names)."""


@lru_cache(maxsize=1)
def av2_sensor_log_index() -> dict[str, int]:
    """{log id: index in av2's TRAIN + VAL + TEST sensor split lists}."""
    from av2.datasets.sensor.splits import TEST, TRAIN, VAL

    return {log_id: i for i, log_id in enumerate((*TRAIN, *VAL, *TEST))}


def _hash_number(log_id: str) -> int:
    digest = hashlib.sha256(log_id.encode()).hexdigest()[:12]
    return OTHER_FIRST + int(digest, 16) % (OTHER_LAST - OTHER_FIRST + 1)


def scene_number(log_id: str) -> int:
    """The preferred number of a log (AV2 logs always get it; others unless another log has it)."""
    index = av2_sensor_log_index().get(log_id)
    return AV2_FIRST + index if index is not None else _hash_number(log_id)


def scene_names_for(log_ids: Iterable[str]) -> dict[str, str]:
    """``{log id: "scene-NNNN"}`` for the logs of one database (see the module doc for the rule)."""
    ids = list(log_ids)
    if len(set(ids)) != len(ids):
        dup = sorted({x for x in ids if ids.count(x) > 1})
        raise SceneNameError(f"log ids must be unique across splits; repeated: {dup}")
    av2 = av2_sensor_log_index()
    names: dict[str, str] = {x: f"scene-{AV2_FIRST + av2[x]:04d}" for x in ids if x in av2}
    others = sorted(x for x in ids if x not in av2)
    span = OTHER_LAST - OTHER_FIRST + 1
    if len(others) > span:
        raise SceneNameError(f"{len(others)} non-AV2 logs exceed the {span} names scene-{OTHER_FIRST}..."
                             f"scene-{OTHER_LAST}")
    taken: set[int] = set()
    for log_id in others:
        n = preferred = _hash_number(log_id)
        while n in taken:
            n = OTHER_FIRST + (n - OTHER_FIRST + 1) % span
        if n != preferred:
            log.warning("scene name collision: log %s hashes to scene-%04d, which a log with a smaller id "
                        "holds; it gets scene-%04d", log_id, preferred, n)
        taken.add(n)
        names[log_id] = f"scene-{n:04d}"
    return {x: names[x] for x in ids}
