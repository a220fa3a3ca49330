"""Scene names: ``scene-NNNN`` outside nuScenes' lists, fixed per log (issue 10, finding 5)."""

from __future__ import annotations

import itertools
import random

import pytest
from av2.datasets.sensor.splits import TEST, TRAIN, VAL
from nuscenes.utils.splits import create_splits_scenes

from nuav2.nuscenes_db.scene_names import SceneNameError, scene_names_for, scene_number

AV2_IDS = [*TRAIN, *VAL, *TEST]


def test_every_av2_sensor_log_has_its_own_number_outside_nuscenes_lists():
    names = scene_names_for(AV2_IDS)
    assert [names[x] for x in AV2_IDS] == [f"scene-{2000 + i:04d}" for i in range(len(AV2_IDS))]
    nuscenes = {s for v in create_splits_scenes().values() for s in v}
    assert not nuscenes & set(names.values())
    assert max(int(s[6:]) for s in nuscenes) < 2000


def test_a_log_keeps_its_name_whatever_else_is_converted():
    rng = random.Random(0)
    others = [f"{i:08x}-0000-0000-0000-000000000000" for i in range(50)]  # in no av2 list
    pool = AV2_IDS[:40] + others
    full = scene_names_for(pool)
    for _ in range(20):
        subset = rng.sample(pool, 15)
        rng.shuffle(subset)
        assert scene_names_for(subset) == {x: full[x] for x in subset} or _has_collision(subset)


def _has_collision(ids: list[str]) -> bool:
    numbers = [scene_number(x) for x in ids]
    return len(set(numbers)) != len(numbers)


def test_other_logs_collide_only_by_hash_and_resolve_by_log_id_order():
    ids = (f"synthetic-{i}" for i in itertools.count())
    seen: dict[int, str] = {}
    while True:  # two ids with the same preferred number (birthday: ~100 tries)
        x = next(ids)
        n = scene_number(x)
        if n in seen:
            a, b = sorted((seen[n], x))
            break
        seen[n] = x
    assert 3000 <= n <= 9999
    names = scene_names_for([b, a])
    assert names[a] == f"scene-{n:04d}" and names[b] != names[a]  # the smaller id keeps the number
    assert names == scene_names_for([a, b])  # whatever the order given
    assert scene_names_for([b]) == {b: f"scene-{n:04d}"}  # alone, b has its own number


def test_impossible_sets_are_clear_errors():
    with pytest.raises(SceneNameError, match="repeated"):
        scene_names_for(["a", "b", "a"])
    with pytest.raises(SceneNameError, match="exceed"):
        scene_names_for([f"log-{i}" for i in range(7001)])
