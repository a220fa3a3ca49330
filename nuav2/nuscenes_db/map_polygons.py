"""Polygon and polyline repair, so the devkit never silently drops (or chokes on) a map record.

The devkit's explorer skips any non-drivable-area polygon with ``is_valid == False`` and runs
shapely overlays on drivable areas, which raise on invalid input. Everything written is
therefore made valid, snapped to the node grid the JSON stores (so the polygon the devkit
rebuilds from the written nodes is the one validated here), oriented (exterior CCW), and
stripped of slivers.
"""

from __future__ import annotations

import numpy as np
import shapely
from shapely.geometry import MultiPolygon, Polygon
from shapely.geometry.polygon import orient

from nuav2.geometry import F64

GRID_M = 1e-4  # node coordinates are stored on this grid (0.1 mm)
SLIVER_AREA_M2 = 0.01  # pieces smaller than 10 cm x 10 cm are dropped
_JOIN_BUFFER_M = 0.005  # welds the lobes of a repaired bow-tie into one polygon (lanes only)


def dedupe_consecutive(xy: np.ndarray, tol_m: float = 1e-3) -> F64:
    """Drop vertices closer than ``tol_m`` to their predecessor (keeps the first)."""
    pts = np.asarray(xy, dtype=np.float64)
    if pts.ndim != 2 or len(pts) == 0:
        return pts.reshape(0, 2) if pts.size == 0 else pts
    keep = np.ones(len(pts), dtype=bool)
    last = pts[0]
    for i in range(1, len(pts)):
        if np.hypot(*(pts[i, :2] - last[:2])) < tol_m:
            keep[i] = False
        else:
            last = pts[i]
    return pts[keep]


def polyline_length(xy: np.ndarray) -> float:
    pts = np.asarray(xy, dtype=np.float64)
    if len(pts) < 2:
        return 0.0
    return float(np.hypot(*np.diff(pts[:, :2], axis=0).T).sum())


def _polygon_pieces(geom) -> list[Polygon]:
    if geom.is_empty:
        return []
    if isinstance(geom, Polygon):
        return [geom]
    if isinstance(geom, MultiPolygon):
        return list(geom.geoms)
    if hasattr(geom, "geoms"):  # GeometryCollection from make_valid: keep areal parts only
        return [p for g in geom.geoms for p in _polygon_pieces(g)]
    return []


def _clean(poly: Polygon) -> Polygon:
    """Orient and drop repeated vertices (rings stay closed; the devkit closes them itself)."""
    return orient(shapely.remove_repeated_points(poly, GRID_M / 2), sign=1.0)


def valid_pieces(geom, min_area_m2: float = SLIVER_AREA_M2) -> list[Polygon]:
    """Valid, grid-snapped, CCW polygons covering ``geom`` (a Polygon/ring-like geometry), slivers dropped."""
    if geom.is_empty:
        return []
    fixed = geom if geom.is_valid else shapely.make_valid(geom)
    snapped = shapely.set_precision(fixed, GRID_M)
    pieces = [_clean(p) for p in _polygon_pieces(snapped) if p.area >= min_area_m2]
    pieces = [p for p in pieces if p.is_valid and not p.is_empty]
    return sorted(pieces, key=lambda p: (-p.area, p.bounds))


def polygon_from_ring(ring_xy: np.ndarray) -> Polygon | None:
    """A shapely Polygon from an unclosed ring, or None when it has fewer than 3 distinct vertices."""
    pts = dedupe_consecutive(np.asarray(ring_xy, dtype=np.float64)[:, :2])
    if len(pts) >= 2 and np.hypot(*(pts[0] - pts[-1])) < 1e-3:
        pts = pts[:-1]
    if len(pts) < 3:
        return None
    return Polygon(pts)


def repair_multi(ring_xy: np.ndarray) -> tuple[list[Polygon], bool]:
    """All valid pieces of a ring (for drivable areas, the devkit's one multi-polygon layer), and
    whether the input needed repair."""
    poly = polygon_from_ring(ring_xy)
    if poly is None:
        return [], True
    return valid_pieces(poly), not poly.is_valid


def repair_single(ring_xy: np.ndarray) -> tuple[Polygon | None, bool]:
    """One valid polygon for a single-polygon layer (lane, crossing), and whether it differs from the input.

    A self-intersecting ring becomes its valid pieces; slivers go; remaining lobes that touch
    (a bow-tie) are welded by a 5 mm buffer; if pieces stay apart, the largest is kept.
    """
    poly = polygon_from_ring(ring_xy)
    if poly is None:
        return None, True
    was_valid = poly.is_valid
    pieces = valid_pieces(poly)
    if not pieces:
        return None, True
    if len(pieces) == 1:
        return pieces[0], not was_valid
    welded = valid_pieces(shapely.unary_union(pieces).buffer(_JOIN_BUFFER_M, join_style="mitre"))
    return (welded[0] if welded else pieces[0]), True


def densify(xy: np.ndarray, max_spacing_m: float) -> tuple[F64, np.ndarray]:
    """Insert vertices so no segment exceeds ``max_spacing_m``; returns (points, index of source segment).

    The geometry is unchanged (new vertices lie on the segments); ``src[i]`` is the input vertex
    index whose outgoing segment point ``i`` lies on, so per-vertex attributes carry over.
    """
    pts = np.asarray(xy, dtype=np.float64)
    if len(pts) < 2:
        return pts.copy(), np.arange(len(pts))
    out, src = [], []
    for i in range(len(pts) - 1):
        seg = pts[i + 1] - pts[i]
        n = max(1, int(np.ceil(np.hypot(*seg[:2]) / max_spacing_m)))
        t = np.arange(n)[:, None] / n
        out.append(pts[i] + t * seg)
        src.append(np.full(n, i))
    out.append(pts[-1:])
    src.append([len(pts) - 1])
    return np.concatenate(out), np.concatenate(src).astype(np.int64)
