"""Road layouts: roads (a centre line and a cross-section) meeting at junctions, built into a map.

``four_way`` is the original intersection (road.py builds its map, unchanged); the others come
from one general builder: each road is a centre polyline with forward lanes on its right and
backward lanes on its left (right-hand traffic), an optional raised median, a shoulder or parking
strip, and sidewalks beyond the kerb. A junction joins road ends at a common centre: its surface
is the union of the arms' stubs with the concave corners rounded, its lanes are cubic curves from
each inbound lane to the outbound lanes it may reach (straight on, the outermost lane turning
right, the innermost turning left), with crosswalks across and stop bars before every arm.

Layouts (``LAYOUTS``): ``arterial`` (3 + 3 lanes, raised median, a midblock crosswalk),
``t_junction`` (a 2 + 2 main road and a 1 + 1 side road), ``curved`` (2 + 2 lanes through arcs
of 30-200 m radius), ``y_junction`` (three arms at skewed angles, the main road bent) and the
original ``four_way``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely
from shapely.geometry import Polygon

from nuav2.geometry import F64
from nuav2.synth import polyline as pl
from nuav2.synth.config import LAYOUTS
from nuav2.synth.road import (
    CORNER_R,
    CROSSWALK,
    DRIVABLE_HALF,
    INTER_HALF,
    LANE_W,
    STOP_BAR,
    CrosswalkSpec,
    LaneSpec,
    RoadLayout,
    arm_length_for,
    build_road_layout,
    rot90,
)

CHUNK_M = 36.0  # lane segments start every 36 m (a multiple of the 12 m dash period)
MEDIAN_GAP_M = 0.3
SIDEWALK_W = 3.5


@dataclass(frozen=True, eq=False)
class Road:
    """A road: centre line (forward direction) and cross-section."""

    centre: F64  # (M, 2)
    n_fwd: int
    n_bwd: int
    median: float = 0.0  # raised median width (0: a double yellow line)
    shoulder: float = 0.0  # drivable strip beyond the outer lane (>= 2.2 m: parking)

    @property
    def right_half(self) -> float:
        return self.median / 2 + self.n_fwd * LANE_W + self.shoulder

    @property
    def left_half(self) -> float:
        return self.median / 2 + self.n_bwd * LANE_W + self.shoulder

    @property
    def length(self) -> float:
        return float(pl.arclength(self.centre)[-1])


@dataclass(frozen=True)
class Junction:
    centre: tuple[float, float]
    edge: float  # every arm's road starts this far from the centre
    arms: tuple[tuple[int, bool], ...]  # (road index, True if the road starts at the junction)


@dataclass(frozen=True, eq=False)
class StreetPlan:
    """What a layout is made of (the map is built from it; actors and furniture are placed along it)."""

    name: str
    roads: tuple[Road, ...]
    junctions: tuple[Junction, ...]
    midblock_crossings: tuple[tuple[int, float], ...] = ()  # (road, arc length) with stop bars

    @property
    def crown_half(self) -> float:
        return max(max(r.right_half, r.left_half) for r in self.roads)


def draw_params(name: str, rng: np.random.Generator) -> dict:
    """The seed's free choices for a layout (drawn once, so the map and the wider world agree)."""
    if name == "curved":
        r1, r2, r3 = rng.uniform(120, 200), rng.uniform(60, 110), rng.uniform(30, 45)
        signs = rng.choice([-1.0, 1.0], 3)
        return {"radii": [r1 * signs[0], r2 * signs[1], r3 * signs[2]], "focus": int(rng.integers(3))}
    if name == "y_junction":
        return {"bend_deg": float(rng.uniform(-25, 25)), "side_deg": float(rng.uniform(235, 300))}
    return {}


def _arm(angle: float, edge: float, reach: float) -> F64:
    u = np.array([np.cos(angle), np.sin(angle)])
    n = max(2, int(np.ceil(reach - edge)) + 1)
    return np.outer(np.linspace(edge, reach, n), u)


def build_plan(name: str, reach: float, params: dict) -> StreetPlan:
    """The layout ``name`` out to ``reach`` metres from its centre."""
    if name not in LAYOUTS:
        raise ValueError(f"layout must be one of {LAYOUTS}, got {name!r}")
    if name == "four_way":
        arm = arm_length_for(reach)
        roads = tuple(
            Road(
                np.array([rot90(k) @ [-INTER_HALF, 0.0], rot90(k) @ [-arm, 0.0]]),
                2,
                2,
                shoulder=DRIVABLE_HALF - 2 * LANE_W,
            )
            for k in range(4)
        )
        return StreetPlan(
            name, roads, (Junction((0.0, 0.0), INTER_HALF, tuple((k, True) for k in range(4))),)
        )
    if name == "arterial":
        n = int(np.ceil(2 * reach)) + 1
        centre = np.column_stack([np.linspace(-reach, reach, n), np.zeros(n)])
        return StreetPlan(name, (Road(centre, 3, 3, median=4.0, shoulder=0.5),), (), ((0, reach),))
    if name == "t_junction":
        arm = arm_length_for(reach)
        main = dict(n_fwd=2, n_bwd=2, shoulder=DRIVABLE_HALF - 2 * LANE_W)
        roads = (
            Road(_arm(np.pi, INTER_HALF, arm), **main),
            Road(_arm(0.0, INTER_HALF, arm), **main),
            Road(_arm(np.pi / 2, INTER_HALF, arm), 1, 1, shoulder=2.5),
        )
        return StreetPlan(name, roads, (Junction((0.0, 0.0), INTER_HALF, ((0, True), (1, True), (2, True))),))
    if name == "y_junction":
        edge = 17.0
        arm = arm_length_for(reach)
        a = np.deg2rad([180.0, params["bend_deg"], params["side_deg"]])
        roads = (
            Road(_arm(a[0], edge, arm), 2, 2, shoulder=2.5),
            Road(_arm(a[1], edge, arm), 2, 2, shoulder=2.5),
            Road(_arm(a[2], edge, arm), 1, 1, shoulder=1.0),
        )
        return StreetPlan(name, roads, (Junction((0.0, 0.0), edge, ((0, True), (1, True), (2, True))),))
    # curved: arcs around the origin, which sits mid-way along the focus arc
    r = params["radii"]
    pattern = [(25.0, 0.0), (55.0, 1 / r[0]), (15.0, 0.0), (50.0, 1 / r[1]), (20.0, 0.0), (45.0, 1 / r[2])]
    focus_s = [25.0 + 27.5, 95.0 + 25.0, 165.0 + 22.5][params["focus"]]
    segs, total = [], 0.0
    while total < focus_s + reach + 1.0:
        for seg in pattern:
            segs.append(seg)
            total += seg[0]
    segs = [(max(reach - focus_s, 0.0) + 1.0, 0.0)] + segs
    xy = pl.from_curvature(segs)
    s0 = max(reach - focus_s, 0.0) + 1.0 + focus_s
    centre = pl.sub(xy, s0 - reach, s0 + reach)
    mid = pl.at(xy, s0)
    head = pl.heading_at(xy, np.array([s0]))[0]
    c, s_ = np.cos(-head), np.sin(-head)
    centre = (centre - mid) @ np.array([[c, -s_], [s_, c]]).T
    return StreetPlan(name, (Road(centre, 2, 2, shoulder=1.0),), ())


def plan_layout(plan: StreetPlan, first_id: int = 40_000_000) -> RoadLayout:
    """The map (lanes, crosswalks, stop bars, drivable areas) of a plan; ``four_way`` uses road.py."""
    if plan.name == "four_way":
        return build_road_layout(float(plan.roads[0].length + INTER_HALF), first_id)
    return _Builder(plan, first_id).build()


def _lane_centre_end(lane: LaneSpec, end: bool) -> tuple[F64, F64]:
    """(left point, right point) at the lane's end (``end``) or start."""
    k = -1 if end else 0
    return lane.left[k], lane.right[k]


class _Builder:
    def __init__(self, plan: StreetPlan, first_id: int):
        self.plan = plan
        self.ids = iter(range(first_id, first_id + 1_000_000))
        self.lanes: dict[int, dict] = {}
        self.fwd: list[list[list[int]]] = []  # road -> lane -> chunk (by arc length)
        self.bwd: list[list[list[int]]] = []

    def _add(self, left: F64, right: F64, lm: str, rm: str, inter: bool) -> int:
        i = next(self.ids)
        self.lanes[i] = dict(left=left, right=right, lm=lm, rm=rm, inter=inter, succ=[], ln=None, rn=None)
        return i

    def _road_lanes(self, road: Road) -> None:
        L = road.length
        cuts = list(np.arange(0.0, L - 1.0, CHUNK_M)) + [L]
        # Cut points become vertices, so neighbouring chunks share their end points exactly.
        s = pl.arclength(road.centre)
        s_all = np.unique(np.concatenate([s, cuts]))
        centre = pl.at(road.centre, s_all)
        idx = [int(np.argmin(np.abs(s_all - c))) for c in cuts]
        m2 = road.median / 2
        inner = "SOLID_YELLOW" if road.median > 0 else "DOUBLE_SOLID_YELLOW"

        def pieces(d: float) -> list[F64]:
            line = pl.offset(centre, d)
            return [line[a : b + 1] for a, b in zip(idx[:-1], idx[1:])]

        fwd, bwd = [], []
        for i in range(road.n_fwd):
            lm = inner if i == 0 else "DASHED_WHITE"
            rm = "SOLID_WHITE" if i == road.n_fwd - 1 else "DASHED_WHITE"
            fwd.append(
                [
                    self._add(a, b, lm, rm, False)
                    for a, b in zip(pieces(-(m2 + i * LANE_W)), pieces(-(m2 + (i + 1) * LANE_W)))
                ]
            )
        for i in range(road.n_bwd):
            lm = inner if i == 0 else "DASHED_WHITE"
            rm = "SOLID_WHITE" if i == road.n_bwd - 1 else "DASHED_WHITE"
            bwd.append(
                [
                    self._add(a[::-1], b[::-1], lm, rm, False)
                    for a, b in zip(pieces(m2 + i * LANE_W), pieces(m2 + (i + 1) * LANE_W))
                ]
            )
        n_chunks = len(cuts) - 1
        for c in range(n_chunks):
            for i in range(road.n_fwd):
                ln = self.lanes[fwd[i][c]]
                if c + 1 < n_chunks:
                    ln["succ"].append(fwd[i][c + 1])
                ln["rn"] = fwd[i + 1][c] if i + 1 < road.n_fwd else None
                ln["ln"] = (
                    fwd[i - 1][c] if i > 0 else (bwd[0][c] if road.median == 0 and road.n_bwd else None)
                )
            for i in range(road.n_bwd):
                ln = self.lanes[bwd[i][c]]
                if c > 0:
                    ln["succ"].append(bwd[i][c - 1])
                ln["rn"] = bwd[i + 1][c] if i + 1 < road.n_bwd else None
                ln["ln"] = (
                    bwd[i - 1][c] if i > 0 else (fwd[0][c] if road.median == 0 and road.n_fwd else None)
                )
        self.fwd.append(fwd)
        self.bwd.append(bwd)

    def _arm_lanes(self, road_i: int, at_start: bool) -> tuple[list[int], list[int], F64]:
        """(inbound lane ids, outbound lane ids (inner to outer), unit direction away from the centre)."""
        road = self.plan.roads[road_i]
        if at_start:
            inbound = [lanes[0] for lanes in self.bwd[road_i]]
            outbound = [lanes[0] for lanes in self.fwd[road_i]]
            u = pl.tangents(road.centre)[0]
        else:
            inbound = [lanes[-1] for lanes in self.fwd[road_i]]
            outbound = [lanes[-1] for lanes in self.bwd[road_i]]
            u = -pl.tangents(road.centre)[-1]
        return inbound, outbound, u

    def _junction(self, j: Junction, crosswalks: list, stop_bars: list, areas: list) -> None:
        arms = [self._arm_lanes(ri, st) for ri, st in j.arms]
        straight_by_pair: dict[tuple[int, int], list[int]] = {}
        for a, (inb, _, ua) in enumerate(arms):
            for b, (_, outb, ub) in enumerate(arms):
                if a == b:
                    continue
                d_in = -ua
                theta = np.arctan2(d_in[0] * ub[1] - d_in[1] * ub[0], d_in @ ub)
                if abs(theta) < np.deg2rad(35):
                    pairs = [(i, i) for i in range(min(len(inb), len(outb)))]
                elif theta > 0:
                    pairs = [(0, 0)]
                else:
                    pairs = [(len(inb) - 1, len(outb) - 1)]
                made = []
                for i, k in pairs:
                    src, dst = self.lanes[inb[i]], self.lanes[outb[k]]
                    chord = float(np.linalg.norm(dst["left"][0] - src["left"][-1]))
                    arm_k = chord / 3 if abs(theta) < np.deg2rad(35) else 0.39 * chord
                    n = max(3, int(np.ceil(chord * 1.3)) + 1)
                    left = pl.resample(pl.bezier(src["left"][-1], d_in, dst["left"][0], ub, arm_k), n)
                    chord_r = float(np.linalg.norm(dst["right"][0] - src["right"][-1]))
                    arm_r = chord_r / 3 if abs(theta) < np.deg2rad(35) else 0.39 * chord_r
                    right = pl.resample(pl.bezier(src["right"][-1], d_in, dst["right"][0], ub, arm_r), n)
                    cid = self._add(left, right, "NONE", "NONE", True)
                    src["succ"].append(cid)
                    self.lanes[cid]["succ"].append(outb[k])
                    made.append(cid)
                if abs(theta) < np.deg2rad(35):
                    straight_by_pair[(a, b)] = made
        for made in straight_by_pair.values():
            for i in range(len(made) - 1):
                self.lanes[made[i]]["rn"] = made[i + 1]
                self.lanes[made[i + 1]]["ln"] = made[i]
        c = np.asarray(j.centre, np.float64)
        stubs = []
        for (ri, st), (inb, _, u) in zip(j.arms, arms):
            road = self.plan.roads[ri]
            n = np.array([-u[1], u[0]])
            lo, hi = (-road.right_half, road.left_half) if st else (-road.left_half, road.right_half)
            stubs.append(Polygon([c + lo * n, c + j.edge * u + lo * n, c + j.edge * u + hi * n, c + hi * n]))
            e1 = np.array(
                [c + (j.edge - CROSSWALK[0]) * u + lo * n, c + (j.edge - CROSSWALK[0]) * u + hi * n]
            )
            e2 = np.array(
                [c + (j.edge - CROSSWALK[1]) * u + lo * n, c + (j.edge - CROSSWALK[1]) * u + hi * n]
            )
            crosswalks.append(CrosswalkSpec(next(self.ids), e1, e2))
            m2 = road.median / 2
            w_in = m2 + len(inb) * LANE_W
            a0, a1 = j.edge + STOP_BAR[0], j.edge + STOP_BAR[1]
            stop_bars.append(
                np.array(
                    [c + a1 * u + m2 * n, c + a0 * u + m2 * n, c + a0 * u + w_in * n, c + a1 * u + w_in * n]
                )
            )
        core = shapely.union_all(stubs).buffer(CORNER_R, quad_segs=8).buffer(-CORNER_R, quad_segs=8)
        core = shapely.simplify(shapely.normalize(core), 1e-6)
        areas.append((next(self.ids), np.asarray(core.exterior.coords)[:-1]))

    def build(self) -> RoadLayout:
        for road in self.plan.roads:
            self._road_lanes(road)
        crosswalks: list[CrosswalkSpec] = []
        stop_bars: list[F64] = []
        areas: list[tuple[int, F64]] = []
        for j in self.plan.junctions:
            self._junction(j, crosswalks, stop_bars, areas)
        for ri, s in self.plan.midblock_crossings:
            road = self.plan.roads[ri]
            p = pl.at(road.centre, np.array([s]))[0]
            u = pl.tangents(pl.sub(road.centre, s - 1.0, s + 1.0))[0]
            n = np.array([-u[1], u[0]])
            lo, hi = -road.right_half, road.left_half
            crosswalks.append(
                CrosswalkSpec(
                    next(self.ids),
                    np.array([p - 1.5 * u + lo * n, p - 1.5 * u + hi * n]),
                    np.array([p + 1.5 * u + lo * n, p + 1.5 * u + hi * n]),
                )
            )
            m2 = road.median / 2
            for sign, width in ((-1.0, m2 + road.n_fwd * LANE_W), (1.0, m2 + road.n_bwd * LANE_W)):
                a0, a1 = sign * 3.0, sign * 3.4  # forward traffic stops before s, backward after
                stop_bars.append(
                    np.array(
                        [
                            p + a0 * u + sign * m2 * n,
                            p + a1 * u + sign * m2 * n,
                            p + a1 * u + sign * width * n,
                            p + a0 * u + sign * width * n,
                        ]
                    )
                )
        for road in self.plan.roads:
            if road.median > 0:  # the island's kerb stands MEDIAN_GAP_M off the inner lanes' paint
                m2 = road.median / 2 - MEDIAN_GAP_M
                sides = [(-road.right_half, -m2), (m2, road.left_half)]
            else:
                sides = [(-road.right_half, road.left_half)]
            for lo, hi in sides:
                ring = np.vstack([pl.offset(road.centre, lo), pl.offset(road.centre, hi)[::-1]])
                areas.append((next(self.ids), ring))
        pred: dict[int, list[int]] = {i: [] for i in self.lanes}
        for i, ln in self.lanes.items():
            for s in ln["succ"]:
                pred[s].append(i)
        lanes = tuple(
            LaneSpec(
                i,
                ln["left"],
                ln["right"],
                ln["lm"],
                ln["rm"],
                ln["inter"],
                tuple(ln["succ"]),
                tuple(sorted(pred[i])),
                ln["ln"],
                ln["rn"],
            )
            for i, ln in sorted(self.lanes.items())
        )
        reach = max(float(np.max(np.abs(r.centre))) for r in self.plan.roads)
        return RoadLayout(reach, lanes, tuple(crosswalks), tuple(areas), tuple(stop_bars))
