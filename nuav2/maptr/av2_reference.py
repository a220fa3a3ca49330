"""Map GT derived straight from the av2 map API: the yardstick for the nuScenes-side GT.

The product path is AV2 map -> map expansion JSON -> devkit ``NuScenesMap`` -> vectorizer.
This module skips the first three steps: it cuts the av2 ``ArgoverseStaticMap`` geometry by
the same rotated patch in the city frame and moves it into the LIDAR_TOP frame, with the same
per-class rules the nuScenes map conversion promises:

- divider: lane boundaries whose paint is not NONE/UNKNOWN (shared boundaries once);
- ped_crossing: crossing polygons (edge1, edge2);
- boundary: outline of the union of drivable areas;
- centerline: av2's ``compute_midpoint_line`` of each lane (1 m spacing, at least 10 points),
  chained through successors.

The protocol steps after the cut (ring orientation, grown/shrunk clipping, line merge,
centerline paths) are the shared pure functions of ``vectorize``. :func:`class_chamfer`
compares two GT sets class by class, independently of how lines are split into instances.
"""

from __future__ import annotations

import math

import numpy as np
import shapely
from shapely.geometry import LineString, Polygon

from nuav2.geometry import F64
from nuav2.maptr.vectorize import (
    CLASSES,
    CONTOUR_MARGIN_M,
    DEFAULT_PATCH,
    MapPatch,
    Vectors,
    as_arrays,
    centerline_paths,
    contour_lines,
    split_lines,
)

UNPAINTED = ("NONE", "UNKNOWN")
CENTERLINE_SPACING_M = 1.0
MIN_CENTERLINE_POINTS = 10


def _valid(poly: Polygon) -> list[Polygon]:
    if poly.is_valid:
        return [poly]
    fixed = shapely.make_valid(poly)
    return [g for g in getattr(fixed, "geoms", [fixed]) if g.geom_type == "Polygon" and g.area > 0]


def _mark(value) -> str:
    return getattr(value, "value", str(value))


def av2_centerline(left_xyz: np.ndarray, right_xyz: np.ndarray) -> F64:
    """Lane centerline by av2's ``compute_midpoint_line`` with max(10, length/1 m + 1) points."""
    from av2.geometry.interpolate import compute_midpoint_line

    def length(p: np.ndarray) -> float:
        return float(np.sum(np.linalg.norm(np.diff(p[:, :2], axis=0), axis=1)))

    n = max(
        MIN_CENTERLINE_POINTS,
        int(math.ceil(max(length(left_xyz), length(right_xyz)) / CENTERLINE_SPACING_M)) + 1,
    )
    mid, _ = compute_midpoint_line(left_xyz[:, :2], right_xyz[:, :2], num_interp_pts=n)
    return np.asarray(mid, dtype=np.float64)[:, :2]


def av2_reference_vectors(
    static_map,
    city_T_lidar: np.ndarray,
    patch_size: tuple[float, float] = DEFAULT_PATCH,
    simplify_m: float = 0.2,
) -> Vectors:
    """GT polylines of one patch from an ``av2.map.map_api.ArgoverseStaticMap``, in LIDAR_TOP xy."""
    patch = MapPatch.from_pose(city_T_lidar, patch_size)
    area = patch.polygon()
    half = patch.half_extent_xy
    lanes = static_map.vector_lane_segments

    seen: set[bytes] = set()
    dividers = []
    for lane_id in sorted(lanes):
        lane = lanes[lane_id]
        for bnd, mark in (
            (lane.left_lane_boundary.xyz, lane.left_mark_type),
            (lane.right_lane_boundary.xyz, lane.right_mark_type),
        ):
            xy = np.asarray(bnd, dtype=np.float64)[:, :2]
            key_f, key_r = (
                np.round(xy * 1000).astype(np.int64).tobytes(),
                np.round(xy[::-1] * 1000).astype(np.int64).tobytes(),
            )
            if _mark(mark) in UNPAINTED or key_f in seen or key_r in seen or len(xy) < 2:
                continue
            seen.add(key_f)
            cut = LineString(xy).intersection(area)
            if not cut.is_empty:
                dividers.append(patch.to_local(cut))
    out: Vectors = as_arrays("divider", split_lines(dividers))

    peds = []
    for pc in static_map.vector_pedestrian_crossings.values():
        for poly in _valid(Polygon(np.asarray(pc.polygon, dtype=np.float64)[:, :2])):
            cut = poly.intersection(area)
            if not cut.is_empty:
                peds.append(patch.to_local(cut))
    out += as_arrays("ped_crossing", contour_lines(peds, half, +CONTOUR_MARGIN_M))

    drivable = []
    for da in static_map.vector_drivable_areas.values():
        for poly in _valid(Polygon(np.asarray(da.xyz, dtype=np.float64)[:, :2])):
            cut = poly.intersection(area)
            if not cut.is_empty:
                drivable.append(patch.to_local(cut))
    out += as_arrays("boundary", contour_lines(drivable, half, -CONTOUR_MARGIN_M))

    pieces: dict[str, list[np.ndarray]] = {}
    for lane_id, lane in lanes.items():
        left = np.asarray(lane.left_lane_boundary.xyz, dtype=np.float64)
        right = np.asarray(lane.right_lane_boundary.xyz, dtype=np.float64)
        outline = _valid(Polygon(np.concatenate([left[:, :2], right[::-1, :2]])))
        if not any(p.intersects(area) for p in outline):
            continue
        cut = LineString(av2_centerline(left, right)).intersection(area)
        parts = split_lines([patch.to_local(cut)]) if not cut.is_empty else []
        if parts:
            pieces[str(lane_id)] = [np.asarray(p.coords) for p in parts]
    links = [(str(a), str(b)) for a, lane in lanes.items() for b in lane.successors if b in lanes]
    out += as_arrays("centerline", centerline_paths(pieces, links, simplify_m))
    return out


def _dense_points(polylines: list[np.ndarray], spacing_m: float) -> F64:
    pts = []
    for p in polylines:
        p = np.asarray(p, dtype=np.float64)[:, :2]
        pts.append(p[:1])
        for a, b in zip(p[:-1], p[1:]):
            n = max(1, int(math.ceil(np.linalg.norm(b - a) / spacing_m)))
            pts.append(a + (b - a) * (np.arange(1, n + 1)[:, None] / n))
    return np.concatenate(pts) if pts else np.zeros((0, 2))


def polyline_set_chamfer(
    a: list[np.ndarray], b: list[np.ndarray], spacing_m: float = 0.05
) -> tuple[float, float]:
    """(mean, max) symmetric chamfer distance between two sets of polylines.

    Each set is densified to ``spacing_m`` and each point measured to the *lines* of the other
    set (not to its points, which would add up to spacing/2 of sampling-phase error). Mean is
    ½ (mean a->b + mean b->a); max is the Hausdorff distance. Both empty gives (0, 0); exactly
    one empty gives (inf, inf).
    """
    from shapely.geometry import MultiLineString

    def lines(ps: list[np.ndarray]) -> MultiLineString:
        return MultiLineString([np.asarray(p, dtype=np.float64)[:, :2] for p in ps if len(p) >= 2])

    pa, pb = _dense_points(a, spacing_m), _dense_points(b, spacing_m)
    if len(pa) == 0 and len(pb) == 0:
        return 0.0, 0.0
    if len(pa) == 0 or len(pb) == 0:
        return math.inf, math.inf
    da = shapely.distance(shapely.points(pa), lines(b))
    db = shapely.distance(shapely.points(pb), lines(a))
    return 0.5 * (float(da.mean()) + float(db.mean())), float(max(da.max(), db.max()))


def class_chamfer(
    ours: Vectors, reference: Vectors, spacing_m: float = 0.05
) -> dict[str, tuple[float, float]]:
    """Per class (mean, max) chamfer between two GT sets of the same patch."""
    return {
        cls: polyline_set_chamfer(
            [p for c, p in ours if c == cls], [p for c, p in reference if c == cls], spacing_m
        )
        for cls in CLASSES
    }
