"""AV2 vector map -> nuScenes map expansion JSON + semantic-prior mask PNG for one location.

One location per log (see ``map_frame``): everything is written in that log's global frame
(city minus a whole-metre offset, so all coordinates are >= 20 m) and the true city offset is
kept in the JSON's ``nuav2`` block. Layers:

- ``drivable_area``: one record per AV2 drivable area, its repaired pieces as ``polygon_tokens``.
- ``road_segment``: one per drivable-area piece (``is_intersection`` false, sharing its polygon),
  plus one per connected patch of intersection-lane polygons clipped to the drivable area
  (``is_intersection`` true). Their union is the drivable area, so MapTR's boundary class
  (union of road_segment and lane polygons) traces the AV2 drivable-area edge.
- ``lane`` / ``lane_connector`` / ``arcline_path_3`` / ``connectivity``: see ``map_lanes``.
- ``ped_crossing``: polygon e1[0], e1[1], e2[1], e2[0] (its convex hull if the edges cross).
- ``road_divider`` / ``lane_divider``: see ``map_dividers``; line nodes at most 1 m apart because
  the devkit's ``get_records_in_patch`` tests line nodes only.
- ``road_block``, ``walkway``, ``stop_line``, ``carpark_area``, ``traffic_light``: present, empty.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import shapely
from shapely.geometry import Polygon

from nuav2.atomic import atomic_write_bytes
from nuav2.geometry import F64
from nuav2.nuscenes_db.map_dividers import extract_dividers
from nuav2.nuscenes_db.map_frame import LOCATION_RE, MARGIN_M, OFFSET_KEY, MapFrame
from nuav2.nuscenes_db.map_geometry_tables import GeometryTables, map_token
from nuav2.nuscenes_db.map_lanes import build_lane_records, segment_type
from nuav2.nuscenes_db.map_mask import (
    RESOLUTION_M,
    canvas_edge_for,
    encode_png,
    rasterize_polygons,
    semantic_prior_filename,
)
from nuav2.nuscenes_db.map_polygons import SLIVER_AREA_M2, densify, repair_multi, valid_pieces
from nuav2.scene import DrivableArea, PedCrossing, VectorMap

EXPANSION_VERSION = "1.3"
LINE_NODE_SPACING_M = 1.0
MIN_CANVAS_EDGE_M = 2 * MARGIN_M
LIST_LAYERS = ("polygon", "line", "node", "drivable_area", "road_segment", "road_block", "lane",
               "ped_crossing", "walkway", "stop_line", "carpark_area", "road_divider", "lane_divider",
               "traffic_light", "lane_connector")


@dataclass(frozen=True)
class MapArtifacts:
    """What ``write_map_expansion`` wrote; ``mask_filename`` goes into the ``map`` table record."""

    location: str
    expansion_path: str  # dataroot-relative, maps/expansion/<location>.json
    mask_filename: str  # dataroot-relative, maps/<md5(location)>.png
    canvas_edge: tuple[float, float]  # metres, [width, height]
    mask_shape: tuple[int, int]  # (rows, cols) at RESOLUTION_M
    expansion_bytes: int
    mask_bytes: int
    stats: dict[str, int]


def _check_finite(vector_map: VectorMap) -> None:
    arrays = [(f"lane {i} boundary", np.concatenate([ln.left_boundary, ln.right_boundary]))
              for i, ln in vector_map.lane_segments.items()]
    arrays += [(f"crossing {i}", np.concatenate([c.edge1, c.edge2]))
               for i, c in vector_map.ped_crossings.items()]
    arrays += [(f"drivable area {i}", a.boundary) for i, a in vector_map.drivable_areas.items()]
    for what, arr in arrays:
        if not np.all(np.isfinite(np.asarray(arr, dtype=np.float64))):
            raise ValueError(f"vector map ({vector_map.city_name}): {what} has NaN/Inf coordinates")


def _shift(xyz: np.ndarray, offset: F64) -> F64:
    out = np.array(xyz, dtype=np.float64, copy=True).reshape(len(xyz), -1)
    out -= offset[: out.shape[1]]
    return out


def to_global(vector_map: VectorMap, frame: MapFrame) -> VectorMap:
    """The map moved from the city frame to the location's global frame (x, y and, where given, z)."""
    off = np.asarray(frame.city_offset, dtype=np.float64)
    lanes = {i: dataclasses.replace(ln, left_boundary=_shift(ln.left_boundary, off),
                                    right_boundary=_shift(ln.right_boundary, off))
             for i, ln in vector_map.lane_segments.items()}
    crossings = {i: PedCrossing(c.id, _shift(c.edge1, off), _shift(c.edge2, off))
                 for i, c in vector_map.ped_crossings.items()}
    areas = {i: DrivableArea(a.id, _shift(a.boundary, off)) for i, a in vector_map.drivable_areas.items()}
    return VectorMap(vector_map.city_name, lanes, crossings, areas)


def _all_xy(vm: VectorMap) -> F64:
    parts = [np.zeros((0, 2))]
    parts += [np.asarray(b)[:, :2]
              for ln in vm.lane_segments.values() for b in (ln.left_boundary, ln.right_boundary)]
    parts += [np.asarray(c.polygon)[:, :2] for c in vm.ped_crossings.values()]
    parts += [np.asarray(a.boundary)[:, :2] for a in vm.drivable_areas.values()]
    return np.concatenate(parts)


def _crossing_polygon(c: PedCrossing) -> Polygon | None:
    pieces, repaired = repair_multi(c.polygon)
    if len(pieces) == 1 and not repaired:
        return pieces[0]
    # Edges given in opposite directions make a bow-tie: the crossing is the quadrilateral they span.
    hull = shapely.convex_hull(shapely.MultiPoint(np.asarray(c.polygon)[:, :2]))
    hull_pieces = valid_pieces(hull) if isinstance(hull, Polygon) else []
    return hull_pieces[0] if hull_pieces else None


def _containing(point, candidates: list[tuple[str, Polygon]]) -> str:
    for token, poly in candidates:
        if poly.covers(point):
            return token
    return ""


def build_map_expansion(vector_map: VectorMap, frame: MapFrame,
                        cover_xy_city: np.ndarray | None = None) -> tuple[dict, np.ndarray, dict[str, int]]:
    """(expansion JSON object, semantic-prior mask, stats) for one location; nothing is written."""
    if not LOCATION_RE.match(frame.location):
        raise ValueError(f"location {frame.location!r} does not match {LOCATION_RE.pattern} "
                         "(nuav2.devkit_compat only admits such names into NuScenesMap)")
    _check_finite(vector_map)
    vm = to_global(vector_map, frame)
    xy = _all_xy(vm)
    if len(xy) and xy.min() < 0:
        raise ValueError(f"location {frame.location}: map reaches global ({xy.min(axis=0).tolist()}) < 0; "
                         f"city_offset {frame.city_offset.tolist()} must be below every map vertex")
    loc = frame.location
    tables = GeometryTables(loc)
    stats: dict[str, int] = {"polygons_repaired": 0, "lanes_dropped": 0, "crossings_dropped": 0,
                             "drivable_areas_dropped": 0}

    # Drivable areas, and one road segment per piece.
    drivable_area, road_segment, drivable_pieces = [], [], []
    seg_candidates: list[tuple[str, Polygon]] = []
    for area_id in sorted(vm.drivable_areas):
        pieces, repaired = repair_multi(vm.drivable_areas[area_id].boundary)
        if not pieces:
            stats["drivable_areas_dropped"] += 1
            continue
        stats["polygons_repaired"] += repaired
        da_token = map_token(loc, "drivable_area", str(area_id))
        poly_tokens = [tables.add_polygon(f"drivable_area/{area_id}/{k}", p) for k, p in enumerate(pieces)]
        drivable_area.append({"token": da_token, "polygon_tokens": poly_tokens, "av2_id": int(area_id)})
        for k, (p, ptok) in enumerate(zip(pieces, poly_tokens)):
            seg_token = map_token(loc, "road_segment", f"drivable_area/{area_id}/{k}")
            road_segment.append({"token": seg_token, "polygon_token": ptok, "is_intersection": False,
                                 "drivable_area_token": da_token})
            seg_candidates.append((seg_token, p))
            drivable_pieces.append((da_token, p))

    # Lanes and lane connectors.
    lanes = build_lane_records(vm.lane_segments, tables)
    stats["lanes_dropped"] = len(lanes.dropped)
    stats["polygons_repaired"] += len(lanes.repaired)

    # Intersections: connected patches of connector polygons, clipped to the drivable area.
    connector_polys = [lanes.polygons[i] for i in sorted(lanes.polygons)
                       if vm.lane_segments[i].is_intersection]
    if connector_polys:
        patches = shapely.unary_union(connector_polys)
        if drivable_pieces:
            patches = shapely.intersection(patches, shapely.unary_union([p for _, p in drivable_pieces]))
        for k, p in enumerate(valid_pieces(patches, min_area_m2=1.0)):
            overlaps = [(p.intersection(dp).area, t) for t, dp in drivable_pieces]
            da_token = max(overlaps)[1] if overlaps and max(overlaps)[0] > 0 else ""
            road_segment.append({"token": map_token(loc, "road_segment", f"intersection/{k}"),
                                 "polygon_token": tables.add_polygon(f"intersection/{k}", p),
                                 "is_intersection": True, "drivable_area_token": da_token})

    # Pedestrian crossings.
    ped_crossing = []
    for cid in sorted(vm.ped_crossings):
        poly = _crossing_polygon(vm.ped_crossings[cid])
        if poly is None:
            stats["crossings_dropped"] += 1
            continue
        ped_crossing.append({"token": map_token(loc, "ped_crossing", str(cid)),
                             "polygon_token": tables.add_polygon(f"ped_crossing/{cid}", poly),
                             "road_segment_token": _containing(poly.representative_point(), seg_candidates),
                             "av2_id": int(cid)})

    # Dividers from painted boundaries.
    dividers: dict[str, list[dict]] = {"road_divider": [], "lane_divider": []}
    for d in extract_dividers(list(vm.lane_segments.values())):
        dense, src = densify(d.xy, LINE_NODE_SPACING_M)
        node_toks = tables.node_tokens(dense, drop_repeats=False)
        key = f"{d.layer}/{d.sources[0][0]}/{d.sources[0][1]}"
        rec = {"token": map_token(loc, d.layer, key), "line_token": tables.add_line(key, node_toks)}
        if d.layer == "road_divider":
            mid = shapely.Point(dense[len(dense) // 2])
            rec["road_segment_token"] = _containing(mid, seg_candidates)
        else:
            rec["lane_divider_segments"] = [
                {"node_token": t, "segment_type": segment_type(d.segment_types[s])}
                for t, s in zip(node_toks, src.tolist())]
        dividers[d.layer].append(rec)

    # Canvas and mask: cover every written node and the caller's points (poses).
    node_xy = np.array([[n["x"], n["y"]] for n in tables.node], dtype=np.float64).reshape(-1, 2)
    cover = node_xy
    if cover_xy_city is not None:
        cover_g = frame.city_to_global_xy(np.asarray(cover_xy_city, dtype=np.float64).reshape(-1, 2))
        cover_g = cover_g[np.all(np.isfinite(cover_g), axis=1)]
        if len(cover_g) and cover_g.min() < 0:
            raise ValueError(f"location {frame.location}: a point to cover lies at global "
                             f"{cover_g.min(axis=0).tolist()} < 0; the map frame offset must be below it")
        cover = np.concatenate([cover, cover_g])
    canvas_edge = canvas_edge_for(cover, MARGIN_M, MIN_CANVAS_EDGE_M)
    mask = rasterize_polygons([p for _, p in drivable_pieces], canvas_edge, RESOLUTION_M)

    expansion: dict = {"version": EXPANSION_VERSION, "canvas_edge": [canvas_edge[0], canvas_edge[1]]}
    layers = {"polygon": tables.polygon, "line": tables.line, "node": tables.node,
              "drivable_area": drivable_area, "road_segment": road_segment, "road_block": [],
              "lane": lanes.lane,
              "ped_crossing": ped_crossing, "walkway": [], "stop_line": [], "carpark_area": [],
              "road_divider": dividers["road_divider"], "lane_divider": dividers["lane_divider"],
              "traffic_light": [], "lane_connector": lanes.lane_connector}
    expansion.update({name: layers[name] for name in LIST_LAYERS})
    expansion["arcline_path_3"] = lanes.arcline_path_3
    expansion["connectivity"] = lanes.connectivity
    expansion["nuav2"] = {
        "source": "av2", "location": loc, "city_name": vector_map.city_name,
        OFFSET_KEY: [float(v) for v in frame.city_offset],
        "note": "city = global + city_offset (x, y, z); the map is 2-D, its z = 0 is the ground "
                "under the log's first pose",
        "semantic_prior": semantic_prior_filename(loc), "semantic_prior_resolution_m": RESOLUTION_M,
    }
    check_polygons_valid(expansion)
    stats.update({name: len(layers[name]) for name in LIST_LAYERS})
    return expansion, mask, stats


def check_polygons_valid(expansion: dict) -> None:
    """Raise if any polygon, rebuilt from the written nodes as the devkit does, is invalid."""
    xy = {n["token"]: (n["x"], n["y"]) for n in expansion["node"]}
    for rec in expansion["polygon"]:
        holes = [[xy[t] for t in h["node_tokens"]] for h in rec["holes"]]
        poly = Polygon([xy[t] for t in rec["exterior_node_tokens"]], holes)
        if not poly.is_valid or poly.area < SLIVER_AREA_M2:
            reason = shapely.is_valid_reason(poly)
            raise RuntimeError(f"polygon {rec['token']} is invalid or a sliver after repair: {reason}")


def write_map_expansion(vector_map: VectorMap, frame: MapFrame, dataroot: Path,
                        cover_xy_city: np.ndarray | None = None) -> MapArtifacts:
    """Write ``maps/expansion/<location>.json`` and the mask PNG under ``dataroot`` (atomically).

    ``cover_xy_city``: extra city points (the log's poses) the mask and canvas must also cover.
    Output bytes depend only on the inputs.
    """
    expansion, mask, stats = build_map_expansion(vector_map, frame, cover_xy_city)
    dataroot = Path(dataroot)
    mask_rel = semantic_prior_filename(frame.location)
    json_rel = f"maps/expansion/{frame.location}.json"
    png = encode_png(mask)
    blob = json.dumps(expansion, separators=(",", ":"), ensure_ascii=False, allow_nan=False).encode()
    atomic_write_bytes(dataroot / mask_rel, png)
    atomic_write_bytes(dataroot / json_rel, blob)
    return MapArtifacts(location=frame.location, expansion_path=json_rel, mask_filename=mask_rel,
                        canvas_edge=(expansion["canvas_edge"][0], expansion["canvas_edge"][1]),
                        mask_shape=(int(mask.shape[0]), int(mask.shape[1])), expansion_bytes=len(blob),
                        mask_bytes=len(png), stats=stats)

