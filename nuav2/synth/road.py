"""The synthetic road network: a 4-way intersection of two 4-lane roads, in the world's local frame.

Local frame: x east, y north, z up, origin at the intersection centre on the (flat) ground.
Everything is built for one approach (traffic arriving from the west, driving +x on the
south half, right-hand traffic) and rotated by 90 degree steps for the other three, so the
lane graph is symmetric and easy to check. The same function builds the map (arms cut at
``arm_length``) and the painted world (arms a bit longer, so paint continues past the map
edge as on a real street).

Cross-section of an arm, measured from the road axis: lanes 0-3.5 and 3.5-7 m per direction
(double yellow at 0, dashed white at 3.5, solid white at 7), a parking strip to 9.5 m (still
drivable), sidewalk to 13 m, then grass and building lots.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely
from shapely.geometry import Polygon, box

from nuav2.geometry import F64

LANE_W = 3.5
ROAD_HALF = 2 * LANE_W  # outer lane edge (solid white)
DRIVABLE_HALF = 9.5  # parking strip edge = curb
SIDEWALK_W = 3.5
INTER_HALF = 14.0  # arms start here; the intersection box is |x|, |y| < INTER_HALF
CORNER_R = INTER_HALF - DRIVABLE_HALF  # curb fillet radius at the corners
DASH_PERIOD = 12.0  # 3 m paint, 9 m gap (US practice); arm lengths are multiples of this
DASH_LEN = 3.0
CHUNK_MAX = 36.0  # lane segments on an arm are at most this long
CROSSWALK = (0.5, 3.5)  # crosswalk spans [INTER_HALF - 3.5, INTER_HALF - 0.5] from the centre
STOP_BAR = (0.1, 0.5)  # stop bar spans [INTER_HALF + 0.1, INTER_HALF + 0.5]
ARC_STEP_M = 1.0

INNER, OUTER = 0, 1


@dataclass(frozen=True)
class LaneSpec:
    """A lane segment; boundaries (N, 2) follow the travel direction."""

    id: int
    left: F64
    right: F64
    left_mark: str
    right_mark: str
    is_intersection: bool
    successors: tuple[int, ...]
    predecessors: tuple[int, ...]
    left_neighbor_id: int | None
    right_neighbor_id: int | None


@dataclass(frozen=True)
class CrosswalkSpec:
    id: int
    edge1: F64  # (2, 2)
    edge2: F64  # (2, 2)

    @property
    def polygon(self) -> F64:
        return np.stack([self.edge1[0], self.edge1[1], self.edge2[1], self.edge2[0]])


@dataclass(frozen=True)
class RoadLayout:
    """Lanes, crosswalks and areas in the local frame (metres, z = 0 is the ground)."""

    arm_length: float
    lanes: tuple[LaneSpec, ...]
    crosswalks: tuple[CrosswalkSpec, ...]
    drivable_areas: tuple[tuple[int, F64], ...]  # (id, (N, 2) unclosed ring)
    stop_bars: tuple[F64, ...]  # (4, 2) polygons

    def lane(self, lane_id: int) -> LaneSpec:
        for ln in self.lanes:
            if ln.id == lane_id:
                return ln
        raise KeyError(lane_id)

    def drivable_union(self):
        return shapely.union_all([Polygon(r) for _, r in self.drivable_areas])

    def sidewalk_area(self):
        """Sidewalk: a band SIDEWALK_W wide around the drivable area (rounded at the corners)."""
        road = self.drivable_union()
        return road.buffer(SIDEWALK_W, quad_segs=16).difference(road)


def rot90(k: int) -> F64:
    c, s = [(1, 0), (0, 1), (-1, 0), (0, -1)][k % 4]
    return np.array([[c, -s], [s, c]], dtype=np.float64)


def _line(x0: float, x1: float, y: float) -> F64:
    return np.array([[x0, y], [x1, y]], dtype=np.float64)


def _arc(center: tuple[float, float], radius: float, a0: float, a1: float) -> F64:
    n = max(2, int(np.ceil(abs(a1 - a0) * radius / ARC_STEP_M)) + 1)
    a = np.linspace(a0, a1, n)
    return np.column_stack([center[0] + radius * np.cos(a), center[1] + radius * np.sin(a)])


def arm_length_for(reach_m: float) -> float:
    """Smallest arm length >= ``reach_m`` that keeps dashes in phase (INTER_HALF + k * DASH_PERIOD)."""
    k = max(1, int(np.ceil((reach_m - INTER_HALF) / DASH_PERIOD)))
    return INTER_HALF + k * DASH_PERIOD


def build_road_layout(arm_length: float, first_id: int = 40_000_000) -> RoadLayout:
    """The full lane graph, crosswalks, stop bars and drivable areas for arms of ``arm_length``."""
    L, E = float(arm_length), INTER_HALF
    if L <= E + 1.0:
        raise ValueError(f"arm_length must exceed {E + 1.0} m, got {L}")
    n_chunks = max(1, int(np.ceil((L - E) / CHUNK_MAX)))
    edges = np.linspace(-L, -E, n_chunks + 1)
    ids = iter(range(first_id, first_id + 100_000))

    # Canonical (arm 0 = west) ids: inbound[k][lane][chunk] travels toward the centre,
    # outbound[k][lane][chunk] away from it (chunk 0 touches the intersection).
    inbound = [[[next(ids) for _ in range(n_chunks)] for _ in range(2)] for _ in range(4)]
    outbound = [[[next(ids) for _ in range(n_chunks)] for _ in range(2)] for _ in range(4)]
    straight = [[next(ids) for _ in range(2)] for _ in range(4)]
    right_turn = [next(ids) for _ in range(4)]
    left_turn = [next(ids) for _ in range(4)]

    lanes: list[LaneSpec] = []
    succ: dict[int, list[int]] = {}

    def add(k: int, lane_id: int, left: F64, right: F64, lm: str, rm: str, inter: bool,
            succs: list[int], ln: int | None, rn: int | None) -> None:
        R = rot90(k)
        lanes.append(LaneSpec(lane_id, left @ R.T, right @ R.T, lm, rm, inter, (), (), ln, rn))
        succ[lane_id] = succs

    marks_in = {INNER: ("DOUBLE_SOLID_YELLOW", "DASHED_WHITE"), OUTER: ("DASHED_WHITE", "SOLID_WHITE")}
    for k in range(4):
        for i in (INNER, OUTER):
            lm, rm = marks_in[i]
            for c in range(n_chunks):
                x0, x1 = edges[c], edges[c + 1]
                # inbound: +x on the south half; left boundary at y = -3.5 i.
                nxt = inbound[k][i][c + 1] if c + 1 < n_chunks else None
                succs = [nxt] if nxt is not None else (
                    [straight[k][i], left_turn[k]] if i == INNER else [straight[k][i], right_turn[k]])
                opp = outbound[k][INNER][n_chunks - 1 - c] if i == INNER else None
                add(k, inbound[k][i][c], _line(x0, x1, -LANE_W * i), _line(x0, x1, -LANE_W * (i + 1)),
                    lm, rm, False, succs,
                    opp if i == INNER else inbound[k][INNER][c],
                    inbound[k][OUTER][c] if i == INNER else None)
                # outbound: -x on the north half, chunk c' = n-1-c covers the same x range.
                co = n_chunks - 1 - c
                nxt_o = [outbound[k][i][co + 1]] if co + 1 < n_chunks else []
                add(k, outbound[k][i][co], _line(x1, x0, LANE_W * i), _line(x1, x0, LANE_W * (i + 1)),
                    lm, rm, False, nxt_o,
                    inbound[k][INNER][c] if i == INNER else outbound[k][INNER][co],
                    outbound[k][OUTER][co] if i == INNER else None)
        for i in (INNER, OUTER):
            add(k, straight[k][i], _line(-E, E, -LANE_W * i), _line(-E, E, -LANE_W * (i + 1)),
                "NONE", "NONE", True, [outbound[(k + 2) % 4][i][0]],
                None if i == INNER else straight[k][INNER], straight[k][OUTER] if i == INNER else None)
        # Right turn from the outer lane into arm k+1 (south), centred on the south-west corner.
        add(k, right_turn[k], _arc((-E, -E), E - LANE_W, np.pi / 2, 0.0), _arc((-E, -E), E - ROAD_HALF,
            np.pi / 2, 0.0), "NONE", "NONE", True, [outbound[(k + 1) % 4][OUTER][0]], None, None)
        # Left turn from the inner lane into arm k+3 (north), centred on the north-west corner.
        add(k, left_turn[k], _arc((-E, E), E, -np.pi / 2, 0.0), _arc((-E, E), E + LANE_W, -np.pi / 2, 0.0),
            "NONE", "NONE", True, [outbound[(k + 3) % 4][INNER][0]], None, None)

    pred: dict[int, list[int]] = {ln.id: [] for ln in lanes}
    for a, bs in succ.items():
        for b in bs:
            pred[b].append(a)
    lanes = [LaneSpec(ln.id, ln.left, ln.right, ln.left_mark, ln.right_mark, ln.is_intersection,
                      tuple(succ[ln.id]), tuple(sorted(pred[ln.id])), ln.left_neighbor_id,
                      ln.right_neighbor_id)
             for ln in sorted(lanes, key=lambda ln: ln.id)]

    crosswalks, stop_bars, areas = [], [], []
    c0, c1 = E - CROSSWALK[1], E - CROSSWALK[0]
    s0, s1 = E + STOP_BAR[0], E + STOP_BAR[1]
    for k in range(4):
        R = rot90(k)
        e1 = np.array([[-c1, -DRIVABLE_HALF], [-c1, DRIVABLE_HALF]])
        e2 = np.array([[-c0, -DRIVABLE_HALF], [-c0, DRIVABLE_HALF]])
        crosswalks.append(CrosswalkSpec(next(ids), e1 @ R.T, e2 @ R.T))
        bar = np.array([[-s1, -ROAD_HALF], [-s0, -ROAD_HALF], [-s0, 0.0], [-s1, 0.0]])
        stop_bars.append(bar @ R.T)
    D = DRIVABLE_HALF
    fillets = [box(-E, -E, E, E).difference(shapely.Point(sx * E, sy * E).buffer(CORNER_R, quad_segs=8))
               .intersection(box(sx * D, sy * D, sx * E, sy * E)) for sx in (-1, 1) for sy in (-1, 1)]
    core = shapely.union_all([box(-E, -D, E, D), box(-D, -E, D, E), *fillets])
    core = shapely.simplify(shapely.normalize(core), 1e-9)
    areas.append((next(ids), np.asarray(core.exterior.coords)[:-1]))
    for k in range(4):
        R = rot90(k)
        rect = np.array([[-L, -D], [-E, -D], [-E, D], [-L, D]])
        areas.append((next(ids), rect @ R.T))
    return RoadLayout(L, tuple(lanes), tuple(crosswalks), tuple(areas), tuple(stop_bars))
