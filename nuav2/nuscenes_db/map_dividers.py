"""Road and lane dividers from AV2's painted lane boundaries.

AV2 repeats a boundary on every lane that touches it: same-direction neighbours share it
verbatim, opposite lanes hold it reversed as both their left boundaries. Each boundary is
kept once (keyed by its mm-rounded vertices, direction-free), only if painted (mark type
not NONE/UNKNOWN). It is a ``road_divider`` when lanes of both directions hold it or its
paint is yellow (US centre lines), else a ``lane_divider``. Boundary pieces of one layer
that meet end to end at a node no third piece touches are chained into one line, as
nuScenes' long dividers are; MapTR takes every divider line as one instance.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from nuav2.geometry import F64
from nuav2.nuscenes_db.map_polygons import dedupe_consecutive, polyline_length
from nuav2.scene import LaneSegment

UNPAINTED = frozenset({"NONE", "UNKNOWN"})
MIN_DIVIDER_LENGTH_M = 0.01


@dataclass(frozen=True)
class DividerLine:
    """One divider polyline; ``segment_types[i]`` is the paint of the segment leaving vertex i."""

    layer: str  # "road_divider" or "lane_divider"
    xy: F64  # (N, 2)
    segment_types: tuple[str, ...]
    sources: tuple[tuple[int, str], ...]  # (lane id, "left"/"right") of every boundary merged in


@dataclass
class _Piece:
    xy: F64
    mark: str
    painted: bool
    directions: set[bool]  # True: seen as stored, False: seen reversed
    sources: list[tuple[int, str]]


def _key(xy: F64) -> bytes:
    return np.round(xy * 1000.0).astype(np.int64).tobytes()


def _node(p: np.ndarray) -> tuple[int, int]:
    return int(round(p[0] * 1000.0)), int(round(p[1] * 1000.0))


def unique_boundaries(lanes: Iterable[LaneSegment]) -> list[_Piece]:
    """Every distinct boundary polyline (direction-free), in first-seen order of sorted lanes."""
    pieces: dict[bytes, _Piece] = {}
    for lane in sorted(lanes, key=lambda ln: ln.id):
        for side, bnd, mark in (("left", lane.left_boundary, lane.left_mark_type),
                                ("right", lane.right_boundary, lane.right_mark_type)):
            xy = dedupe_consecutive(np.asarray(bnd, dtype=np.float64)[:, :2])
            if len(xy) < 2 or polyline_length(xy) < MIN_DIVIDER_LENGTH_M:
                continue
            fwd, rev = _key(xy), _key(xy[::-1])
            painted = mark not in UNPAINTED
            if fwd in pieces or rev in pieces:
                piece = pieces[fwd] if fwd in pieces else pieces[rev]
                piece.directions.add(fwd in pieces)
                piece.sources.append((lane.id, side))
                if painted and not piece.painted:
                    piece.mark, piece.painted = mark, True
                continue
            pieces[fwd] = _Piece(xy, mark, painted, {True}, [(lane.id, side)])
    return list(pieces.values())


def _layer(piece: _Piece) -> str:
    both_directions = len(piece.directions) == 2
    return "road_divider" if both_directions or "YELLOW" in piece.mark else "lane_divider"


def _chain(pieces: list[_Piece], layer: str) -> list[DividerLine]:
    """Merge pieces through nodes touched by exactly two piece ends (undirected); the first piece sets the
    direction."""
    ends: dict[tuple[int, int], list[int]] = defaultdict(list)
    for i, p in enumerate(pieces):
        ends[_node(p.xy[0])].append(i)
        ends[_node(p.xy[-1])].append(i)
    used = [False] * len(pieces)

    def next_piece(node: tuple[int, int]) -> int | None:
        touching = ends[node]
        free = [k for k in touching if not used[k]]
        return free[0] if len(touching) == 2 and len(free) == 1 else None

    lines = []
    for i, first in enumerate(pieces):
        if used[i]:
            continue
        used[i] = True
        xy, types, sources = first.xy, [first.mark] * (len(first.xy) - 1), list(first.sources)
        for forward in (True, False):  # grow from the end, then from the start
            while (j := next_piece(_node(xy[-1] if forward else xy[0]))) is not None:
                used[j] = True
                node = _node(xy[-1] if forward else xy[0])
                nxy = pieces[j].xy if _node(pieces[j].xy[0]) == node else pieces[j].xy[::-1]
                ntypes = [pieces[j].mark] * (len(nxy) - 1)
                sources += pieces[j].sources
                if forward:
                    xy, types = np.concatenate([xy, nxy[1:]]), types + ntypes
                else:
                    xy, types = np.concatenate([nxy[::-1][:-1], xy]), ntypes + types
        lines.append(DividerLine(layer, xy, tuple(types) + (types[-1],), tuple(sources)))
    return lines


def extract_dividers(lanes: Iterable[LaneSegment]) -> list[DividerLine]:
    """Deduplicated, chained road and lane dividers from the painted boundaries of ``lanes``."""
    painted = [p for p in unique_boundaries(lanes) if p.painted]
    out: list[DividerLine] = []
    for layer in ("road_divider", "lane_divider"):
        out += _chain([p for p in painted if _layer(p) == layer], layer)
    return out
