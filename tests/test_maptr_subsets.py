"""Scene-level fraction subsets and the equivalent-epoch factor (MapGS paper, less-data study)."""

from __future__ import annotations

import pytest

from nuav2.maptr.subsets import (
    PAPER_FRACTIONS,
    epochs_for,
    equivalent_epoch_factor,
    nominal_equivalent_epoch_factor,
    scene_fraction_subset,
)

SCENES = [f"scene-{i:04d}" for i in range(700)]


def test_fraction_subsets_have_the_right_size_and_are_nested_per_seed():
    subsets = {f: scene_fraction_subset(SCENES, f, seed=3) for f in PAPER_FRACTIONS}
    assert [len(subsets[f]) for f in PAPER_FRACTIONS] == [35, 70, 175]
    assert set(subsets[0.05]) < set(subsets[0.10]) < set(subsets[0.25])
    assert subsets[0.10] == [s for s in SCENES if s in set(subsets[0.10])]  # original order kept


def test_subsets_are_deterministic_per_seed_and_differ_across_seeds():
    a = scene_fraction_subset(SCENES, 0.1, seed=0)
    assert a == scene_fraction_subset(SCENES, 0.1, seed=0)
    assert a == scene_fraction_subset(list(reversed(SCENES)), 0.1, seed=0)[::-1]  # independent of input order
    assert a != scene_fraction_subset(SCENES, 0.1, seed=1)


def test_subset_edge_cases():
    assert scene_fraction_subset(["scene-0001"], 0.05) == ["scene-0001"]  # at least one scene
    assert scene_fraction_subset([], 0.5) == []
    assert scene_fraction_subset(SCENES, 1.0) == SCENES
    with pytest.raises(ValueError, match="fraction"):
        scene_fraction_subset(SCENES, 0.0)
    with pytest.raises(ValueError, match="unique"):
        scene_fraction_subset(["a", "a"], 0.5)


def test_equivalent_epoch_matches_the_paper_numbers():
    # "one equivalent epoch on the 5 %, 10 % and 25 % subsets corresponds to 20, 10 and 4 actual epochs"
    assert [epochs_for(1, nominal_equivalent_epoch_factor(f)) for f in PAPER_FRACTIONS] == [20, 10, 4]
    # with true keyframe counts the factor is the ratio of dataset sizes (iterations match)
    assert equivalent_epoch_factor(28130, 1407) == pytest.approx(19.9929, abs=1e-4)
    assert epochs_for(2, equivalent_epoch_factor(28130, 1407)) == 40
    assert epochs_for(0, 20.0) == 0
    with pytest.raises(ValueError):
        equivalent_epoch_factor(0, 10)
    with pytest.raises(ValueError):
        nominal_equivalent_epoch_factor(1.5)
