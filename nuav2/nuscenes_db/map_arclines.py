"""Lane centerlines from AV2 boundaries, encoded as the devkit's ``arcline_path_3`` pieces.

AV2 stores no centerline: like av2's ``compute_midpoint_line``, both boundaries are resampled
evenly by chordal arc length and averaged. av2 uses 10 points per lane, which cuts up to
0.7 m off curved lanes of the fixture map, so the count grows with length (1 m spacing,
at least 10). The polyline is written as a chain of straight arcline pieces (``LSL`` with
``segment_length [0, L, 0]``): the devkit's ``discretize`` walks each straight piece from its
``start_pose`` along its yaw, so every polyline vertex is reproduced exactly and the points
in between lie on the polyline.
"""

from __future__ import annotations

import math

import numpy as np
import shapely
from shapely.geometry import LineString

from nuav2.geometry import F64
from nuav2.nuscenes_db.map_polygons import dedupe_consecutive, polyline_length

CENTERLINE_SPACING_M = 1.0
MIN_CENTERLINE_POINTS = 10  # av2's NUM_CENTERLINE_INTERP_PTS
# Any non-zero radius: a straight piece has zero-length curved parts, but the devkit divides by it.
STRAIGHT_PIECE_RADIUS_M = 999.0
_COLLINEAR_TOL_M = 1e-3


def resample_by_arclength(points: np.ndarray, n: int) -> F64:
    """``n`` points evenly spaced by chordal arc length along a polyline (2-D or 3-D).

    A polyline of zero length (one point, or all points equal) yields ``n`` copies of its
    first point, which turns a pinched boundary into the pivot of a fan when averaged.
    """
    pts = dedupe_consecutive(np.asarray(points, dtype=np.float64), tol_m=1e-9)
    if len(pts) == 0:
        raise ValueError("cannot resample an empty polyline")
    if len(pts) == 1:
        return np.repeat(pts, n, axis=0)
    cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    target = np.linspace(0.0, cum[-1], n)
    out = np.stack([np.interp(target, cum, pts[:, k]) for k in range(pts.shape[1])], axis=1)
    out[0], out[-1] = pts[0], pts[-1]
    return out


def centerline_from_boundaries(left: np.ndarray, right: np.ndarray,
                               spacing_m: float = CENTERLINE_SPACING_M,
                               min_points: int = MIN_CENTERLINE_POINTS) -> F64:
    """(N, 2) centerline: mean of both boundaries resampled to N = max(min_points, length/spacing + 1)."""
    length = max(polyline_length(left), polyline_length(right))
    n = max(min_points, int(math.ceil(length / spacing_m)) + 1)
    mid = 0.5 * (resample_by_arclength(left, n) + resample_by_arclength(right, n))
    return mid[:, :2]


def drop_collinear(xy: np.ndarray, tol_m: float = _COLLINEAR_TOL_M) -> F64:
    """Remove vertices within ``tol_m`` of the line through their neighbours (Douglas-Peucker)."""
    pts = dedupe_consecutive(np.asarray(xy, dtype=np.float64)[:, :2])
    if len(pts) < 3:
        return pts
    simplified = shapely.simplify(LineString(pts), tol_m, preserve_topology=False)
    return np.asarray(simplified.coords, dtype=np.float64)


def straight_arcline_pieces(xy: np.ndarray, decimals: int = 4) -> list[dict]:
    """One straight ``arcline_path_3`` piece per polyline segment (vertices rounded to the node grid)."""
    pts = dedupe_consecutive(np.round(np.asarray(xy, dtype=np.float64)[:, :2], decimals))
    pieces = []
    for (x0, y0), (x1, y1) in zip(pts[:-1].tolist(), pts[1:].tolist()):
        yaw = math.atan2(y1 - y0, x1 - x0)
        length = math.hypot(x1 - x0, y1 - y0)
        pieces.append({
            "start_pose": [x0, y0, yaw],
            "end_pose": [x1, y1, yaw],
            "shape": "LSL",
            "radius": STRAIGHT_PIECE_RADIUS_M,
            "segment_length": [0.0, length, 0.0],
        })
    return pieces
