"""Vectorized local-map GT (MapTRv2 protocol) from any nuScenes-format dataroot.

Per keyframe, the map is cut by a rectangle centred on LIDAR_TOP and rotated by its yaw
(60 m along lidar y = forward, 30 m along lidar x = right, by default), moved into that
frame and turned into four classes of polylines:

- ``divider``: road_divider + lane_divider lines clipped to the patch (multi-parts split);
- ``ped_crossing``: union of crossing polygons, rings oriented (exterior CW, holes CCW),
  clipped by the patch *grown* 0.2 m so rings stay closed, line-merged;
- ``boundary``: union of road_segment + lane polygons, oriented, clipped by the patch
  *shrunk* 0.2 m so the artificial patch-edge segments disappear, line-merged;
- ``centerline``: lane + lane_connector centerlines (devkit ``discretize_lanes`` at 0.5 m,
  xy rounded to mm), chained through ``connectivity`` into root-to-leaf paths, simplified 0.2 m.

Geometry is read once per map through the devkit's ``NuScenesMap`` (``extract_line``,
``extract_polygon``, ``discretize_lanes``, ``get_incoming/outgoing_lane_ids``), skipping
invalid polygons exactly as the devkit's explorer does, and cut per sample with vectorised
shapely 2 calls instead of the explorer's per-record loop (same result, see tests).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import shapely
from shapely.geometry import LinearRing, LineString, Polygon, box
from shapely.geometry.base import BaseGeometry

from nuav2.geometry import F64, T_from_quat_trans, yaw_of
from nuav2.maptr.ring_needles import drop_needles, is_sliver

log = logging.getLogger(__name__)

CLASSES = ("divider", "ped_crossing", "boundary", "centerline")
CLASS_IDS = {name: i for i, name in enumerate(CLASSES)}
DEFAULT_PATCH = (60.0, 30.0)  # (along lidar y = forward, along lidar x = right), metres
CONTOUR_MARGIN_M = 0.2
CENTERLINE_RESOLUTION_M = 0.5
CENTERLINE_SIMPLIFY_M = 0.2
NODE_DECIMALS = 3
MAX_CENTERLINE_PATHS = 5000
UNION_GRID_M = 1e-9
MIN_RING_AREA_M2 = 1e-6

Vectors = list[tuple[str, F64]]


# ----------------------------------------------------------------------------------------------
# The patch: a rotated rectangle in the global frame and the map from global to LIDAR_TOP xy.
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class MapPatch:
    """Rectangle centred at ``center_xy`` (global) whose local x-axis has heading ``yaw``.

    Local coordinates are the LIDAR_TOP frame's xy (yaw only, as MapTR): x right within
    ±width/2, y forward within ±length/2.
    """

    center_xy: tuple[float, float]
    yaw: float
    length_m: float = DEFAULT_PATCH[0]
    width_m: float = DEFAULT_PATCH[1]

    @staticmethod
    def from_pose(global_T_lidar: np.ndarray, patch: tuple[float, float] = DEFAULT_PATCH) -> MapPatch:
        T = np.asarray(global_T_lidar, dtype=np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise ValueError(f"global_T_lidar must be a finite 4x4 matrix, got shape {T.shape}")
        length, width = float(patch[0]), float(patch[1])
        if not (length > 0 and width > 0):
            raise ValueError(f"patch size must be positive, got {patch}")
        return MapPatch((float(T[0, 3]), float(T[1, 3])), yaw_of(T[:3, :3]), length, width)

    @property
    def half_extent_xy(self) -> tuple[float, float]:
        return self.width_m / 2.0, self.length_m / 2.0

    def local_box(self, margin_m: float = 0.0) -> Polygon:
        hx, hy = self.half_extent_xy
        return box(-hx - margin_m, -hy - margin_m, hx + margin_m, hy + margin_m)

    def local_to_global_xy(self, xy_local: np.ndarray) -> F64:
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        p = np.asarray(xy_local, dtype=np.float64).reshape(-1, 2)
        return np.column_stack(
            [c * p[:, 0] - s * p[:, 1] + self.center_xy[0], s * p[:, 0] + c * p[:, 1] + self.center_xy[1]]
        )

    def global_to_local_xy(self, xy_global: np.ndarray) -> F64:
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        p = np.asarray(xy_global, dtype=np.float64).reshape(-1, 2) - np.asarray(self.center_xy)
        return np.column_stack([c * p[:, 0] + s * p[:, 1], -s * p[:, 0] + c * p[:, 1]])

    def polygon(self) -> Polygon:
        """The patch in the global frame."""
        hx, hy = self.half_extent_xy
        corners = np.array([[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy]])
        return Polygon(self.local_to_global_xy(corners))

    def to_local(self, geoms):
        """Shapely geometry (or array of them) from global into patch-local coordinates."""
        return shapely.transform(geoms, self.global_to_local_xy)


# ----------------------------------------------------------------------------------------------
# Pure geometry: the protocol's steps on shapely inputs already in the patch-local frame.
# ----------------------------------------------------------------------------------------------


def split_lines(geoms: Iterable[BaseGeometry]) -> list[LineString]:
    """Flatten (Multi)LineStrings and collections into single lines of positive length."""
    out: list[LineString] = []
    for g in geoms:
        if g is None or g.is_empty:
            continue
        if g.geom_type == "LineString" or g.geom_type == "LinearRing":
            if g.length > 0:
                out.append(LineString(g.coords))
        elif hasattr(g, "geoms"):
            out.extend(split_lines(g.geoms))
    return out


def _polygons(geoms: Iterable[BaseGeometry]) -> list[Polygon]:
    out: list[Polygon] = []
    for g in geoms:
        if g is None or g.is_empty:
            continue
        if g.geom_type == "Polygon":
            out.append(g)
        elif hasattr(g, "geoms"):
            out.extend(_polygons(g.geoms))
    return out


def contour_lines(
    polygons: Iterable[BaseGeometry], half_extent_xy: tuple[float, float], margin_m: float
) -> list[LineString]:
    """Outlines of the union of ``polygons``: exterior rings clockwise, holes counter-clockwise,
    each clipped by the local box grown by ``margin_m`` (negative shrinks), then line-merged.

    With a positive margin a ring clipped by the patch keeps its patch-edge segment and stays
    closed (crossings); with a negative one that segment is dropped (road boundaries).
    """
    polys = [p for p in _polygons(polygons) if p.area > 0]
    if not polys:
        return []
    # Pieces clipped one by one and moved into the patch frame no longer share edges bit for bit;
    # a plain union then leaves zero-area sliver holes along them. Snapping to a nanometre grid
    # removes those, and any ring that still encloses (almost) nothing is dropped. Gaps wider than
    # the grid (a vertex a fraction of a mm off its neighbour's edge) leave needles and sliver
    # rings: cut the needles, drop the slivers, and orient what is left again.
    union = shapely.unary_union(polys, grid_size=UNION_GRID_M)
    hx, hy = half_extent_xy
    clip = box(-hx - margin_m, -hy - margin_m, hx + margin_m, hy + margin_m)
    lines: list[LineString] = []
    for poly in _polygons([union]):
        rings = []
        for k, r in enumerate((poly.exterior, *poly.interiors)):
            ring = LinearRing(drop_needles(np.asarray(r.coords)))
            area = Polygon(ring).area
            if area < MIN_RING_AREA_M2 or is_sliver(area, ring.length):
                continue
            if ring.is_ccw == (k == 0):  # exterior clockwise, holes counter-clockwise
                ring = LinearRing(ring.coords[::-1])
            rings.append(ring)
        for ring in rings:
            cut = ring.intersection(clip)
            if cut.is_empty:
                continue
            if cut.geom_type == "MultiLineString":
                cut = shapely.line_merge(cut)
            lines.extend(split_lines([cut]))
    return lines


def centerline_paths(
    pieces: dict[str, Sequence[np.ndarray]],
    links: Iterable[tuple[str, str]],
    simplify_m: float = CENTERLINE_SIMPLIFY_M,
    max_paths: int = MAX_CENTERLINE_PATHS,
    decimals: int = NODE_DECIMALS,
) -> list[LineString]:
    """Chain lane centerlines into every root-to-leaf path of the lane graph.

    ``pieces[token]`` are the lane's clipped centerline parts in driving order; ``links`` are
    (from_lane, to_lane) pairs. Points rounded to ``decimals`` are graph nodes, so a lane end
    and its successor's start that coincide become one node. Paths start at nodes without
    incoming edges and end at nodes without outgoing ones; shared prefixes are kept, as in
    MapTRv2. More than ``max_paths`` paths (a combinatorial junction) are cut with a warning.
    """
    succ: dict[tuple, list[tuple]] = {}
    has_pred: set[tuple] = set()

    def add_edge(a: tuple, b: tuple) -> None:
        out = succ.setdefault(a, [])
        succ.setdefault(b, [])
        if a != b and b not in out:
            out.append(b)
            has_pred.add(b)

    ends: dict[str, tuple[tuple, tuple]] = {}
    for token in sorted(pieces):
        parts = [np.round(np.asarray(p, dtype=np.float64)[:, :2], decimals) for p in pieces[token]]
        parts = [p for p in parts if len(p) >= 2]
        if not parts:
            continue
        for p in parts:
            nodes = [tuple(v) for v in p.tolist()]
            for a, b in zip(nodes[:-1], nodes[1:]):
                if a != b:
                    add_edge(a, b)
        ends[token] = (tuple(parts[0][0].tolist()), tuple(parts[-1][-1].tolist()))
    for a, b in sorted(set(links)):
        if a in ends and b in ends and ends[a][1] != ends[b][0]:
            add_edge(ends[a][1], ends[b][0])
    roots = sorted(n for n in succ if n not in has_pred and succ[n])
    out: list[LineString] = []
    for root in roots:
        for path in _simple_paths_to_leaves(succ, root):
            if len(out) >= max_paths:
                log.warning(
                    "centerline graph has more than %d root-to-leaf paths; keeping the first %d",
                    max_paths,
                    max_paths,
                )
                return out
            line = LineString(path)
            if simplify_m > 0:
                line = line.simplify(simplify_m, preserve_topology=True)
            if line.length > 0:
                out.append(line)
    return out


def _simple_paths_to_leaves(succ: dict[tuple, list[tuple]], root: tuple):
    """Depth-first simple paths from ``root`` to nodes without successors (networkx's
    ``all_simple_paths(G, root, leaves)`` order, without its per-node view overhead)."""
    path, on_path, stack = [root], {root}, [iter(succ[root])]
    while stack:
        nxt = next(stack[-1], None)
        if nxt is None:
            stack.pop()
            on_path.discard(path.pop())
            continue
        if nxt in on_path:
            continue
        if not succ[nxt]:
            yield [*path, nxt]
            continue
        path.append(nxt)
        on_path.add(nxt)
        stack.append(iter(succ[nxt]))


def as_arrays(cls: str, lines: Iterable[LineString]) -> Vectors:
    return [(cls, np.asarray(line.coords, dtype=np.float64)[:, :2]) for line in lines]


# ----------------------------------------------------------------------------------------------
# Reading one map location through the devkit.
# ----------------------------------------------------------------------------------------------


@dataclass
class _Layer:
    tokens: list[str]
    geoms: np.ndarray  # shapely geometries, global frame
    tree: shapely.STRtree

    @staticmethod
    def build(tokens: list[str], geoms: list[BaseGeometry]) -> _Layer:
        arr = np.array(geoms, dtype=object)
        return _Layer(tokens, arr, shapely.STRtree(arr))

    def hits(self, patch_global: Polygon) -> np.ndarray:
        """Sorted indices of records that truly intersect the patch."""
        if len(self.tokens) == 0:
            return np.zeros(0, dtype=np.int64)
        return np.sort(self.tree.query(patch_global, predicate="intersects"))

    def clipped(self, patch_global: Polygon) -> tuple[list[str], np.ndarray]:
        """Tokens and geometries (global) of records that truly intersect the patch, clipped."""
        if len(self.tokens) == 0:
            return [], np.zeros(0, dtype=object)
        idx = self.hits(patch_global)
        cut = shapely.intersection(self.geoms[idx], patch_global)
        keep = ~shapely.is_empty(cut)
        return [self.tokens[i] for i in idx[keep]], cut[keep]


class LocalMapVectorizer:
    """GT vectors of one ``NuScenesMap`` for any patch; the map's geometry is extracted once.

    The ``NuScenesMap`` itself (~5 MB of JSON records for one AV2 log) is released after the
    build; the kept geometry is ~0.1 MB, so a loader can hold hundreds of per-log maps.
    """

    def __init__(
        self,
        nusc_map,
        centerline_resolution_m: float = CENTERLINE_RESOLUTION_M,
        centerline_simplify_m: float = CENTERLINE_SIMPLIFY_M,
    ):
        self.map = nusc_map
        self.map_name = getattr(nusc_map, "map_name", "?")
        self.centerline_simplify_m = centerline_simplify_m
        self.dropped_invalid: dict[str, int] = {}
        self.lines = {name: self._line_layer(name) for name in ("road_divider", "lane_divider")}
        self.polys = {name: self._polygon_layer(name) for name in ("ped_crossing", "road_segment", "lane")}
        self._build_centerlines(centerline_resolution_m)
        if any(self.dropped_invalid.values()):
            log.warning(
                "map %s: the devkit skips invalid polygons, so these lose GT: %s",
                self.map_name,
                self.dropped_invalid,
            )
        self.map = None  # only needed while building

    def _line_layer(self, name: str) -> _Layer:
        tokens, geoms = [], []
        for rec in getattr(self.map, name):
            line = self.map.extract_line(rec["line_token"])
            if not line.is_empty:
                tokens.append(rec["token"])
                geoms.append(line)
        return _Layer.build(tokens, geoms)

    def _valid_polygon(self, layer: str, rec: dict) -> Polygon | None:
        if rec.get("polygon_token") is None:
            return None
        poly = self.map.extract_polygon(rec["polygon_token"])
        if not poly.is_valid:  # the explorer's _get_layer_polygon skips these silently
            self.dropped_invalid[layer] = self.dropped_invalid.get(layer, 0) + 1
            return None
        return poly

    def _polygon_layer(self, name: str) -> _Layer:
        tokens, geoms = [], []
        for rec in getattr(self.map, name):
            poly = self._valid_polygon(name, rec)
            if poly is not None:
                tokens.append(rec["token"])
                geoms.append(poly)
        return _Layer.build(tokens, geoms)

    def _build_centerlines(self, resolution_m: float) -> None:
        tokens, polys, lines = [], [], []
        for layer in ("lane", "lane_connector"):
            for rec in getattr(self.map, layer):
                poly = self._valid_polygon(layer, rec)
                if poly is None:
                    continue
                poses = self.map.discretize_lanes([rec["token"]], resolution_m)[rec["token"]]
                xy = np.round(np.asarray(poses, dtype=np.float64).reshape(-1, 3)[:, :2], NODE_DECIMALS)
                if len(xy) < 2:
                    continue
                tokens.append(rec["token"])
                polys.append(poly)
                lines.append(LineString(xy))
        self.lane_polys = _Layer.build(tokens, polys)
        self.lane_centerlines = np.array(lines, dtype=object)  # aligned with self.lane_polys.tokens
        self.lane_links: list[tuple[str, str]] = []
        for tok in tokens:
            self.lane_links += [(pred, tok) for pred in self.map.get_incoming_lane_ids(tok)]
            self.lane_links += [(tok, succ) for succ in self.map.get_outgoing_lane_ids(tok)]

    def vectors(self, patch: MapPatch) -> Vectors:
        """Unresampled GT polylines ``[(class, (N, 2) float64)]`` in the patch-local frame."""
        patch_global = patch.polygon()
        half = patch.half_extent_xy
        out: Vectors = []
        div = [
            patch.to_local(self.lines[n].clipped(patch_global)[1]) for n in ("road_divider", "lane_divider")
        ]
        out += as_arrays("divider", split_lines(np.concatenate(div)))
        ped = patch.to_local(self.polys["ped_crossing"].clipped(patch_global)[1])
        out += as_arrays("ped_crossing", contour_lines(ped, half, +CONTOUR_MARGIN_M))
        road = [patch.to_local(self.polys[n].clipped(patch_global)[1]) for n in ("road_segment", "lane")]
        out += as_arrays("boundary", contour_lines(np.concatenate(road), half, -CONTOUR_MARGIN_M))
        idx = self.lane_polys.hits(patch_global)
        cuts = patch.to_local(shapely.intersection(self.lane_centerlines[idx], patch_global))
        pieces: dict[str, list[np.ndarray]] = {}
        for i, cut in zip(idx, cuts):
            parts = split_lines([cut])
            if parts:
                pieces[self.lane_polys.tokens[i]] = [np.asarray(p.coords) for p in parts]
        out += as_arrays("centerline", centerline_paths(pieces, self.lane_links, self.centerline_simplify_m))
        return out


# ----------------------------------------------------------------------------------------------
# Samples of a nuScenes database.
# ----------------------------------------------------------------------------------------------


def global_T_lidar_of_sample(nusc, sample_token: str, channel: str = "LIDAR_TOP") -> F64:
    """Pose of the sample's key LIDAR_TOP: ego_pose @ calibrated_sensor."""
    sample = nusc.get("sample", sample_token)
    if channel not in sample["data"]:
        raise ValueError(
            f"{nusc.dataroot}/{nusc.version}: sample {sample_token} has no {channel} "
            f"(channels: {sorted(sample['data'])}); MapTR GT is built in the {channel} frame"
        )
    sd = nusc.get("sample_data", sample["data"][channel])
    ego = nusc.get("ego_pose", sd["ego_pose_token"])
    cs = nusc.get("calibrated_sensor", sd["calibrated_sensor_token"])
    return T_from_quat_trans(ego["rotation"], ego["translation"]) @ T_from_quat_trans(
        cs["rotation"], cs["translation"]
    )


def _map_json_path(dataroot: str | Path, location: str) -> Path:
    return Path(dataroot) / "maps" / "expansion" / f"{location}.json"


class MapGT:
    """GT vectors for the samples of one dataroot; one vectorizer per map location, built lazily."""

    def __init__(
        self,
        dataroot: str | Path,
        patch: tuple[float, float] = DEFAULT_PATCH,
        centerline_simplify_m: float = CENTERLINE_SIMPLIFY_M,
    ):
        self.dataroot = Path(dataroot)
        self.patch = patch
        self.centerline_simplify_m = centerline_simplify_m
        self._by_location: dict[str, LocalMapVectorizer] = {}

    def vectorizer(self, location: str) -> LocalMapVectorizer:
        if location not in self._by_location:
            from nuscenes.map_expansion.map_api import NuScenesMap

            path = _map_json_path(self.dataroot, location)
            if not path.is_file():
                raise FileNotFoundError(
                    f"{path}: map expansion for location {location!r} not found "
                    f"(needed for the vectorized map GT)"
                )
            try:
                nusc_map = NuScenesMap(dataroot=str(self.dataroot), map_name=location)
            except (ValueError, KeyError, AssertionError, TypeError) as e:  # JSONDecodeError is a ValueError
                raise ValueError(
                    f"{path}: the devkit cannot load this map expansion ({type(e).__name__}: {e})"
                ) from e
            self._by_location[location] = LocalMapVectorizer(
                nusc_map, centerline_simplify_m=self.centerline_simplify_m
            )
        return self._by_location[location]

    def sample_patch(self, nusc, sample_token: str, lidar_T_patch: np.ndarray | None = None) -> MapPatch:
        """The keyframe's LIDAR_TOP patch, or (``lidar_T_patch``) a patch in a frame moved from it."""
        global_T_patch = global_T_lidar_of_sample(nusc, sample_token)
        if lidar_T_patch is not None:
            global_T_patch = global_T_patch @ lidar_T_patch
        return MapPatch.from_pose(global_T_patch, self.patch)

    def sample_vectors(self, nusc, sample_token: str, lidar_T_patch: np.ndarray | None = None) -> Vectors:
        sample = nusc.get("sample", sample_token)
        location = nusc.get("log", nusc.get("scene", sample["scene_token"])["log_token"])["location"]
        return self.vectorizer(location).vectors(self.sample_patch(nusc, sample_token, lidar_T_patch))


def gt_vectors_for_split(
    dataroot: str | Path, version: str, split: str, patch: tuple[float, float] = DEFAULT_PATCH
) -> dict[str, Vectors]:
    """{sample_token: [(class, (N, 2) float64 polyline in LIDAR_TOP xy)]} for every keyframe of
    ``split`` (from ``<version>/splits.json``, else the devkit's built-in lists), unresampled."""
    from nuscenes.nuscenes import NuScenes

    from nuav2.maptr.subsets import split_sample_tokens
    from nuav2.progress import progress_bar

    nusc = NuScenes(version=version, dataroot=str(dataroot), verbose=False)
    gt = MapGT(dataroot, patch)
    tokens = split_sample_tokens(nusc, split)
    bar = progress_bar(tokens, desc=f"map GT {split}", unit="sample")
    return {tok: gt.sample_vectors(nusc, tok) for tok in bar}
