"""AV2 lane segments -> ``lane`` / ``lane_connector`` records, centerlines and connectivity.

Non-intersection lanes become ``lane`` records and intersection lanes ``lane_connector``
records, as in nuScenes. A lane's polygon is its left boundary followed by its reversed right
boundary. ``connectivity`` comes from successors only (AV2 predecessors miss about half the
links), inverted for ``incoming``; ids outside the local map are dropped, and a lane dropped
as degenerate is bridged (its predecessors link to its successors) so paths stay connected.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from shapely.geometry import Polygon

from nuav2.nuscenes_db.map_arclines import centerline_from_boundaries, drop_collinear, straight_arcline_pieces
from nuav2.nuscenes_db.map_geometry_tables import GeometryTables, map_token
from nuav2.nuscenes_db.map_polygons import polyline_length, repair_single
from nuav2.scene import LaneSegment

MIN_CENTERLINE_LENGTH_M = 0.01
LANE_TYPES = {"VEHICLE": "CAR", "BUS": "CAR", "BIKE": "BIKE"}


def segment_type(av2_mark_type: str) -> str:
    """nuScenes divider segment type for an AV2 mark type (unpainted is nuScenes' "NIL")."""
    return "NIL" if av2_mark_type in ("NONE", "UNKNOWN", "") else av2_mark_type


@dataclass
class LaneRecords:
    lane: list[dict] = field(default_factory=list)
    lane_connector: list[dict] = field(default_factory=list)
    arcline_path_3: dict[str, list[dict]] = field(default_factory=dict)
    connectivity: dict[str, dict[str, list[str]]] = field(default_factory=dict)
    polygons: dict[int, Polygon] = field(default_factory=dict)  # kept lane id -> written polygon
    token_of: dict[int, str] = field(default_factory=dict)  # kept lane id -> record token
    dropped: list[int] = field(default_factory=list)
    repaired: list[int] = field(default_factory=list)


def lane_token(location: str, lane_id: int) -> str:
    return map_token(location, "lane", str(lane_id))


def _divider_segments(tables: GeometryTables, boundary: np.ndarray, mark: str) -> list[dict]:
    kind = segment_type(mark)
    return [{"node_token": t, "segment_type": kind} for t in tables.node_tokens(boundary[:, :2])]


def _resolve_successors(lane_id: int, lanes: dict[int, LaneSegment], kept: set[int]) -> list[int]:
    """Kept successors of ``lane_id``, looking through dropped lanes; dangling ids vanish."""
    out: list[int] = []
    stack, seen = list(lanes[lane_id].successors)[::-1], {lane_id}
    while stack:
        s = stack.pop()
        if s in seen or s not in lanes:
            continue
        seen.add(s)
        if s in kept:
            if s not in out:
                out.append(s)
        else:
            stack.extend(list(lanes[s].successors)[::-1])
    return out


def build_lane_records(lanes: dict[int, LaneSegment], tables: GeometryTables) -> LaneRecords:
    """Records for every non-degenerate lane (boundaries already in the global frame)."""
    loc = tables.location
    rec = LaneRecords()
    for lane_id in sorted(lanes):
        lane = lanes[lane_id]
        left, right = np.asarray(lane.left_boundary, np.float64), np.asarray(lane.right_boundary, np.float64)
        ring = np.concatenate([left[:, :2], right[::-1, :2]])
        poly, changed = repair_single(ring)
        center = drop_collinear(centerline_from_boundaries(left, right))
        if poly is None or polyline_length(center) < MIN_CENTERLINE_LENGTH_M:
            rec.dropped.append(lane_id)
            continue
        if changed:
            rec.repaired.append(lane_id)
        token = lane_token(loc, lane_id)
        # Edge lines keep both nodes even when the boundaries meet, so a line never has one node.
        from_nodes = tables.node_tokens(np.stack([left[0, :2], right[0, :2]]), drop_repeats=False)
        to_nodes = tables.node_tokens(np.stack([left[-1, :2], right[-1, :2]]), drop_repeats=False)
        edge_from = tables.add_line(f"lane/{lane_id}/from_edge", from_nodes)
        edge_to = tables.add_line(f"lane/{lane_id}/to_edge", to_nodes)
        record = {
            "token": token,
            "polygon_token": tables.add_polygon(f"lane/{lane_id}", poly),
            "lane_type": LANE_TYPES.get(lane.lane_type, "CAR"),
            "from_edge_line_token": edge_from,
            "to_edge_line_token": edge_to,
            "left_lane_divider_segments": _divider_segments(tables, left, lane.left_mark_type),
            "right_lane_divider_segments": _divider_segments(tables, right, lane.right_mark_type),
            "av2_id": int(lane_id),
            "av2_lane_type": lane.lane_type,
        }
        (rec.lane_connector if lane.is_intersection else rec.lane).append(record)
        rec.arcline_path_3[token] = straight_arcline_pieces(center)
        rec.polygons[lane_id] = poly
        rec.token_of[lane_id] = token

    kept = set(rec.token_of)
    outgoing = {a: _resolve_successors(a, lanes, kept) for a in sorted(kept)}
    incoming: dict[int, list[int]] = {a: [] for a in sorted(kept)}
    for a in sorted(kept):
        for b in outgoing[a]:
            incoming[b].append(a)
    for a in sorted(kept):
        rec.connectivity[rec.token_of[a]] = {
            "incoming": [rec.token_of[b] for b in incoming[a]],
            "outgoing": [rec.token_of[b] for b in outgoing[a]],
        }
    return rec
