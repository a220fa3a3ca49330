"""Conformance checks for one map-expansion JSON (``maps/expansion/<location>.json``).

Why: ``NuScenesMap`` loads almost anything, then MapTR's converter fails far away (ValueError
on a lane without a connectivity entry, ZeroDivisionError on a zero arcline radius) or drops
data silently (invalid polygons, lanes without arclines). Each rule names the devkit behaviour
it protects. Problems go to ``add(table, token, field, message, check)`` under the table name
``expansion/<location>``; nothing here raises on bad data.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Callable, Iterator
from pathlib import Path

import shapely

from nuav2.nuscenes_db.validate_tables import read_json

AddProblem = Callable[[str, str, str, str, str], None]  # (table, token, field, message, check)
_Problem = Callable[[str, str, str, str], None]  # the same, bound to one expansion file

MIN_MAP_VERSION = "1.3"  # the devkit compares version *strings*: '1.10' < '1.3'
GEOMETRIC_LAYERS = ("polygon", "line", "node")
POLYGON_LAYERS = ("road_segment", "road_block", "lane", "ped_crossing", "walkway", "stop_line",
                  "carpark_area", "lane_connector")  # one polygon_token each; drivable_area: polygon_tokens
LINE_LAYERS = ("road_divider", "lane_divider", "traffic_light")
LIST_LAYERS = GEOMETRIC_LAYERS + ("drivable_area",) + POLYGON_LAYERS + LINE_LAYERS
DICT_LAYERS = ("arcline_path_3", "connectivity")
ARC_SHAPES = ("LSL", "LSR", "RSL", "RSR", "LRL", "RLR")
STOP_LINE_CUES = {"PED_CROSSING": ("ped_crossing_tokens", "ped_crossing"),
                  "TURN_STOP": ("ped_crossing_tokens", "ped_crossing"),
                  "TRAFFIC_LIGHT": ("traffic_light_tokens", "traffic_light"),
                  "STOP_SIGN": None, "YIELD": None}


def validate_map_expansion(path: Path, location: str, add: AddProblem) -> None:
    """Report every way ``path`` would break ``NuScenesMap`` or MapTR's map GT extraction."""
    table = f"expansion/{location}"

    def problem(token: str, field: str, message: str, check: str) -> None:
        add(table, token, field, message, check)

    if not path.is_file():
        problem("", "", f"map expansion file missing: {path}", "missing_map")
        return
    try:
        obj = read_json(path)
    except (OSError, ValueError) as e:
        problem("", "", f"cannot parse {path}: {e}", "bad_json")
        return
    if not isinstance(obj, dict):
        problem("", "", f"{path} holds a JSON {type(obj).__name__}, not an object", "bad_json")
        return
    _check_header(obj, problem)
    layers = _layers(obj, problem)
    index = {name: {r["token"]: r for r in recs} for name, recs in layers.items()}
    node_xy = _check_nodes(layers["node"], problem)
    for r in layers["line"]:
        toks = _token_list(r, "node_tokens", index["node"], "line", "node", problem)
        if toks is not None and len(toks) < 2:
            problem(r["token"], "line.node_tokens", f"{len(toks)} node(s): a LineString needs at least 2",
                    "map_geometry")
    polygons = _polygon_geometries(layers["polygon"], index["node"], node_xy, problem)
    _check_layer_refs(layers, index, polygons, problem)
    _check_lanes(layers, index, obj, problem)


def _check_header(obj: dict, problem: _Problem) -> None:
    version = obj.get("version")
    if not isinstance(version, str):
        problem("", "version", f"must be a string >= {MIN_MAP_VERSION!r} (without one the devkit assumes "
                "'1.0' and rejects the map as outdated)", "map_header")
    elif version < MIN_MAP_VERSION:
        problem("", "version", f"{version!r} < {MIN_MAP_VERSION!r} by string comparison: the devkit rejects "
                "it as outdated", "map_header")
    edge = obj.get("canvas_edge")
    if not (isinstance(edge, list) and len(edge) == 2 and all(_is_finite(v) and v > 0 for v in edge)):
        problem("", "canvas_edge", "must be [width, height] with both > 0 (the explorer divides by them), "
                f"got {edge!r:.60}", "map_header")


def _layers(obj: dict, problem: _Problem) -> dict[str, list[dict]]:
    """The 15 list layers keeping records with a unique string token (the others are reported)."""
    out: dict[str, list[dict]] = {}
    for name in LIST_LAYERS:
        recs = obj.get(name)
        if not isinstance(recs, list):
            problem("", name, "layer missing" if recs is None else "layer must be a list", "map_layer")
            recs = []
        kept, seen = [], set()
        for i, r in enumerate(recs):
            tok = r.get("token") if isinstance(r, dict) else None
            if not isinstance(tok, str) or not tok:
                problem("", name, f"record #{i} is not an object with a non-empty string token", "map_record")
            elif tok in seen:
                problem(tok, name, "duplicate token in layer", "duplicate_token")
            else:
                seen.add(tok)
                kept.append(r)
        out[name] = kept
    for name in DICT_LAYERS:
        if not isinstance(obj.get(name), dict):
            problem("", name, "layer missing" if obj.get(name) is None else "layer must be an object keyed "
                    "by token", "map_layer")
    return out


def _check_nodes(nodes: list[dict], problem: _Problem) -> dict[str, tuple[float, float]]:
    xy: dict[str, tuple[float, float]] = {}
    for r in nodes:
        x, y = r.get("x"), r.get("y")
        if not (_is_finite(x) and _is_finite(y)):
            problem(r["token"], "node", f"x, y must be finite numbers, got {x!r:.30}, {y!r:.30}", "map_node")
            continue
        if x < 0 or y < 0:
            problem(r["token"], "node", f"negative coordinate ({x}, {y}): the map mask and render canvas "
                    "start at (0, 0)", "coordinates")
        xy[r["token"]] = (float(x), float(y))
    return xy


def _token_list(r: dict, field: str, target: dict, layer: str, target_name: str,
                problem: _Problem) -> list[str] | None:
    """``r[field]`` if it is a list of tokens that all resolve in ``target``; else report and None."""
    toks = r.get(field)
    if not isinstance(toks, list):
        problem(r["token"], f"{layer}.{field}", f"must be a list of {target_name} tokens, got {toks!r:.40}",
                "map_record")
        return None
    bad = [t for t in toks if not _resolves(t, target)]
    for t in bad:
        problem(r["token"], f"{layer}.{field}", f"{t!r:.40} not found in {target_name}", "map_reference")
    return None if bad else toks


def _polygon_geometries(polys: list[dict], node_index: dict, xy: dict,
                        problem: _Problem) -> dict[str, shapely.Polygon | None]:
    """Shapely polygon per polygon token, built as the explorer builds it; None where it cannot be."""
    out: dict[str, shapely.Polygon | None] = {}
    for r in polys:
        tok = r["token"]
        out[tok] = None
        ext = _token_list(r, "exterior_node_tokens", node_index, "polygon", "node", problem)
        holes = r.get("holes")
        if not isinstance(holes, list) or not all(isinstance(h, dict) for h in holes):
            problem(tok, "polygon.holes", "must be a list of {'node_tokens': [...]}", "map_record")
            continue
        rings = [_token_list({"token": tok, "node_tokens": h.get("node_tokens")}, "node_tokens", node_index,
                             "polygon.holes", "node", problem) for h in holes]
        if ext is None or any(ring is None for ring in rings):
            continue
        if len(ext) < 3:
            problem(tok, "polygon.exterior_node_tokens", f"{len(ext)} node(s): a polygon needs at least 3",
                    "map_geometry")
            continue
        short = [len(ring) for ring in rings if 0 < len(ring) < 3]  # the explorer skips empty holes
        if short:
            problem(tok, "polygon.holes", f"a hole with {short[0]} node(s): a ring needs at least 3",
                    "map_geometry")
        elif all(t in xy for t in ext) and all(t in xy for ring in rings for t in ring):  # else: bad node
            interiors = [[xy[t] for t in ring] for ring in rings if ring]
            out[tok] = shapely.Polygon([xy[t] for t in ext], interiors)
    return out


def _check_layer_refs(layers: dict, index: dict, polygons: dict, problem: _Problem) -> None:
    """Every layer's geometry reference resolves, and every polygon the explorer reads is valid."""
    reported: set[str] = set()

    def polygon_ref(layer: str, rec_token: str, poly_token) -> None:
        if not _resolves(poly_token, index["polygon"]):
            problem(rec_token, f"{layer}.polygon_token", f"{poly_token!r:.40} not found in polygon",
                    "map_reference")
            return
        geom = polygons.get(poly_token)
        if geom is not None and poly_token not in reported and not geom.is_valid:
            reported.add(poly_token)
            problem(rec_token, layer, f"polygon {poly_token} is invalid ({shapely.is_valid_reason(geom)}): "
                    "the explorer silently drops it", "invalid_polygon")

    for r in layers["drivable_area"]:
        toks = _token_list(r, "polygon_tokens", index["polygon"], "drivable_area", "polygon", problem)
        for t in toks or ():
            polygon_ref("drivable_area", r["token"], t)
    for layer in POLYGON_LAYERS:
        for r in layers[layer]:
            polygon_ref(layer, r["token"], r.get("polygon_token"))
    for layer in LINE_LAYERS:
        for r in layers[layer]:
            if not _resolves(r.get("line_token"), index["line"]):
                problem(r["token"], f"{layer}.line_token", f"{r.get('line_token')!r:.40} not found in line",
                        "map_reference")
    for r in layers["stop_line"]:
        kind = r.get("stop_line_type")
        if not isinstance(kind, str) or kind not in STOP_LINE_CUES:
            problem(r["token"], "stop_line.stop_line_type",
                    f"{kind!r:.40} is not one of {sorted(STOP_LINE_CUES)}", "map_record")
        elif STOP_LINE_CUES[kind]:
            field, target = STOP_LINE_CUES[kind]
            _token_list(r, field, index[target], "stop_line", target, problem)
    for r in layers["lane"]:
        for side in ("left_lane_divider_segments", "right_lane_divider_segments"):
            segs = r.get(side)
            if not isinstance(segs, list) or not all(isinstance(s, dict) for s in segs):
                problem(r["token"], f"lane.{side}", "must be a list of {node_token, segment_type}",
                        "map_record")
                continue
            for s in segs:
                node = s.get("node_token")
                if not _resolves(node, index["node"]):
                    problem(r["token"], f"lane.{side}", f"node_token {node!r:.40} not found in node",
                            "map_reference")


def _check_lanes(layers: dict, index: dict, obj: dict, problem: _Problem) -> None:
    """Every lane and connector has a connectivity entry and a drawable arcline path."""
    connectivity = obj.get("connectivity") if isinstance(obj.get("connectivity"), dict) else {}
    arclines = obj.get("arcline_path_3") if isinstance(obj.get("arcline_path_3"), dict) else {}
    lane_like = {**index["lane"], **index["lane_connector"]}
    for layer in ("lane", "lane_connector"):
        for r in layers[layer]:
            tok = r["token"]
            conn = connectivity.get(tok)
            if conn is None:
                problem(tok, "connectivity", f"{layer} has no connectivity entry (MapTR's converter calls "
                        "get_incoming/outgoing_lane_ids and gets ValueError)", "connectivity")
            elif not isinstance(conn, dict):
                problem(tok, "connectivity", "entry must be {incoming: [...], outgoing: [...]}",
                        "connectivity")
            else:
                for key in ("incoming", "outgoing"):
                    links = conn.get(key)
                    if not isinstance(links, list):
                        problem(tok, "connectivity", f"{key!r} must be a list of lane tokens",
                                "connectivity")
                        continue
                    for t in links:
                        if not _resolves(t, lane_like):
                            problem(tok, "connectivity", f"{key} {t!r:.40} is not a lane or lane_connector",
                                    "connectivity")
            pieces = arclines.get(tok)
            if not isinstance(pieces, list) or not pieces:
                problem(tok, "arcline_path_3", f"{layer} has no arcline path (discretize gives an empty "
                        "centerline, silently)", "arcline")
                continue
            for k, piece in enumerate(pieces):
                msg = _arcline_problem(piece)
                if msg:
                    problem(tok, "arcline_path_3", f"piece {k}: {msg}", "arcline")


def _arcline_problem(piece) -> str | None:
    if not isinstance(piece, dict):
        return "must be an object"
    for key in ("start_pose", "end_pose"):
        pose = piece.get(key)
        if not (isinstance(pose, list) and len(pose) == 3 and all(_is_finite(v) for v in pose)):
            return f"{key} must be [x, y, yaw] finite numbers, got {pose!r:.60}"
    if not isinstance(piece.get("shape"), str) or piece["shape"] not in ARC_SHAPES:
        return f"shape {piece.get('shape')!r:.20} is not one of {ARC_SHAPES}"
    radius = piece.get("radius")
    if not _is_finite(radius) or radius == 0:
        return f"radius must be a finite non-zero number (the devkit divides by it), got {radius!r:.20}"
    seg = piece.get("segment_length")
    if not (isinstance(seg, list) and len(seg) == 3 and all(_is_finite(v) and v >= 0 for v in seg)
            and sum(seg) > 0):
        return f"segment_length must be 3 non-negative numbers with a positive sum, got {seg!r:.60}"
    return None


def _resolves(token, index: dict) -> bool:
    return isinstance(token, str) and token in index


def _is_finite(v) -> bool:
    return type(v) in (int, float) and math.isfinite(v)


@contextlib.contextmanager
def _devkit_accepts(location: str) -> Iterator[None]:
    """Let ``NuScenesMap`` open a non-nuScenes location (it asserts a hard-coded list), then restore it."""
    from nuscenes.map_expansion import map_api

    added = location not in map_api.locations
    if added:
        map_api.locations.append(location)
    try:
        yield
    finally:
        if added:
            map_api.locations.remove(location)


def devkit_load_maps(dataroot: Path, locations: list[str], add: AddProblem) -> None:
    """Open each map with the real ``NuScenesMap`` and run what MapTR's converter runs on every lane."""
    from nuscenes.map_expansion.map_api import NuScenesMap

    for loc in locations:
        if not (dataroot / "maps" / "expansion" / f"{loc}.json").is_file():
            continue  # reported as missing_map
        try:
            with _devkit_accepts(loc):
                nmap = NuScenesMap(dataroot=str(dataroot), map_name=loc)
            tokens = [r["token"] for r in nmap.lane + nmap.lane_connector]
            for tok in tokens:
                nmap.get_incoming_lane_ids(tok)
                nmap.get_outgoing_lane_ids(tok)
            nmap.discretize_lanes(tokens, 0.5)
            for layer in ("drivable_area",) + POLYGON_LAYERS:
                for r in getattr(nmap, layer):
                    for t in r.get("polygon_tokens", [r.get("polygon_token")]):
                        nmap.extract_polygon(t)
            for layer in LINE_LAYERS:
                for r in getattr(nmap, layer):
                    nmap.extract_line(r["line_token"])
        except Exception as e:
            add(f"expansion/{loc}", "", "", f"NuScenesMap('{loc}') failed: {type(e).__name__}: {e}", "devkit")
