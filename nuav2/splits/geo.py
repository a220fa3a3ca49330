"""Geo-disjoint splits by connected components of nearby scenes, and the leakage statistic."""

from __future__ import annotations

import copy
import logging
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from nuav2.splits.names import DISCARDED, HOLDOUT, LEAKAGE_RADIUS_M, SPLITS, Positions

log = logging.getLogger(__name__)


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
    # samples per split, kept with ``members`` (summing the members at every cost made the split
    # quadratic in the number of scenes)
    totals: dict[str, int] = field(default_factory=lambda: dict.fromkeys((*SPLITS, DISCARDED), 0))

    def move(self, scenes: Iterable[int], to: str, source: str | None = None) -> None:
        """Put ``scenes`` into split ``to``, taking them out of ``source`` first if given."""
        scenes = set(scenes)
        if source is not None:
            taken = scenes & self.members[source]
            self.members[source] -= taken
            self.totals[source] -= int(self.sizes[list(taken)].sum())
        new = scenes - self.members[to]
        self.members[to] |= new
        self.totals[to] += int(self.sizes[list(new)].sum())

    def count(self, split: str) -> int:
        return self.totals[split]

    def deficit(self, split: str) -> float:
        return self.target[split] - self.count(split)

    def cost(self, moved: Mapping[str, int] | None = None) -> float:
        """How far the split is from its ratios: squared relative errors of the splits' sample
        counts, plus the discarded samples weighed like a train shortfall (dropping data is never
        free, even where train is over its share). ``moved`` adds samples to splits first."""
        moved = moved or {}
        err = sum(((self.count(s) + moved.get(s, 0) - t) / t) ** 2 for s, t in self.target.items() if t > 0)
        scale = self.target["train"] if self.target["train"] > 0 else float(self.sizes.sum())
        return err + ((self.count(DISCARDED) + moved.get(DISCARDED, 0)) / scale) ** 2


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


ASSIGN_RULES = ("fit", "fit_else_cost", "cost")


def _assign_and_carve(
    rule: str,
    comps: list[list[int]],
    target: dict[str, float],
    sizes: np.ndarray,
    adj: list[set[int]],
    positions: Positions,
    scenes: Sequence[str],
    rng: np.random.Generator,
) -> _State:
    """One candidate split. Whole components, largest first, go: ``fit``: to the split furthest
    below its ratio that they fit (its shortfall plus 10 % of its target), else to train;
    ``fit_else_cost``: the same, else where the cost is least; ``cost``: where the cost is least.
    Then val/test regions are carved out of train while a carve lowers the cost (``rng`` picks
    where each carve starts)."""
    state = _State(sizes, target)
    slack = {s: 0.1 * target[s] for s in SPLITS}
    open_splits = [s for s in SPLITS if target[s] > 0]
    for comp in comps:
        size = int(sizes[comp].sum())
        dest = None
        if rule != "cost":
            by_need = sorted(open_splits, key=lambda s: -state.deficit(s) / target[s])
            dest = next((s for s in by_need if size <= state.deficit(s) + slack[s]), None)
            if dest is None and rule == "fit":
                dest = "train"
        if dest is None:
            dest = min(open_splits, key=lambda s: state.cost({s: size}))
        state.move(comp, dest)
    for split in HOLDOUT:  # carve what whole components could not give, while that is worth its ring
        while state.deficit(split) > slack[split]:
            train_comps = [c for c in _components_within(state.members["train"], adj) if len(c) > 1]
            if not train_comps:
                break
            comp = max(train_comps, key=lambda c: (int(sizes[c].sum()), -min(c)))
            region, ring = _carve_region(comp, state.deficit(split), adj, positions, scenes, sizes, rng)
            ring &= state.members["train"]
            got, lost = int(sizes[region].sum()), int(sizes[list(ring)].sum())
            if state.cost({split: got, "train": -got - lost, DISCARDED: lost}) >= state.cost():
                break  # the carve (and the train scenes it discards) would leave the split worse
            state.move(region, split, source="train")
            state.move(ring, DISCARDED, source="train")
    return state


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
    adj = scene_adjacency(scene_positions, city_of, min_distance_m, scenes)
    # No single greedy rule is best: "fit" meets the ratios where small components can fill the
    # holdouts, "cost" where a component fits no share. Each runs in full; the closest result wins.
    rng = np.random.default_rng(seed)
    comps = _components(adj)
    comps = [comps[i] for i in rng.permutation(len(comps))]  # seed decides among equal sizes
    comps.sort(key=lambda c: -int(sizes[c].sum()))
    runs = [_assign_and_carve(rule, comps, target, sizes, adj, scene_positions, scenes, copy.deepcopy(rng))
            for rule in ASSIGN_RULES]  # each carves with the generator as the permutation left it
    state = min(runs, key=lambda st: st.cost())  # first of equals: "fit"
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
