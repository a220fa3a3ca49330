"""AV2 vector map -> nuScenes map expansion + mask, checked through the real devkit and av2 map API."""

from __future__ import annotations

import json
import math
from pathlib import Path

import matplotlib
import numpy as np
import pytest
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st
from shapely.geometry import LineString, Point, Polygon

import nuav2.devkit_compat  # noqa: F401  (the lead imports it from nuav2/__init__.py)
from nuav2.nuscenes_db.map_arclines import (
    CENTERLINE_SPACING_M,
    MIN_CENTERLINE_POINTS,
    centerline_from_boundaries,
    resample_by_arclength,
    straight_arcline_pieces,
)
from nuav2.nuscenes_db.map_dividers import extract_dividers
from nuav2.nuscenes_db.map_expansion import LIST_LAYERS, build_map_expansion, to_global, write_map_expansion
from nuav2.nuscenes_db.map_frame import MARGIN_M, MapFrame, map_frame_for
from nuav2.nuscenes_db.map_polygons import densify, polyline_length
from nuav2.scene import DrivableArea, LaneSegment, PedCrossing, VectorMap

matplotlib.use("Agg")

from nuscenes.map_expansion.arcline_path_utils import discretize_lane  # noqa: E402
from nuscenes.map_expansion.bitmap import BitMap  # noqa: E402
from nuscenes.map_expansion.map_api import NuScenesMap  # noqa: E402
from nuscenes.utils.map_mask import MapMask  # noqa: E402

CM = 0.01


# ---------------------------------------------------------------- real fixture map


@pytest.fixture(scope="module")
def av2_map(av2_fixture_log: Path):
    from av2.map.map_api import ArgoverseStaticMap

    return ArgoverseStaticMap.from_map_dir(av2_fixture_log / "map", build_raster=False)


@pytest.fixture(scope="module")
def poses_xy_city(av2_fixture_log: Path) -> np.ndarray:
    import pyarrow.feather as feather

    t = feather.read_table(av2_fixture_log / "city_SE3_egovehicle.feather")
    return np.stack([t["tx_m"].to_numpy(), t["ty_m"].to_numpy()], axis=1)


@pytest.fixture(scope="module")
def written(av2_fixture_log: Path, poses_xy_city, tmp_path_factory):
    from converters.av2.map import vector_map_from_dir

    vm = vector_map_from_dir(av2_fixture_log / "map")
    map_xy = np.concatenate([np.asarray(a.boundary)[:, :2] for a in vm.drivable_areas.values()])
    frame = map_frame_for(vm.city_name, av2_fixture_log.name, np.concatenate([map_xy, poses_xy_city]))
    dataroot = tmp_path_factory.mktemp("nuav2_maps")
    artifacts = write_map_expansion(vm, frame, dataroot, cover_xy_city=poses_xy_city)
    nmap = NuScenesMap(str(dataroot), map_name=frame.location)
    return vm, frame, dataroot, artifacts, nmap


def _xy(nmap: NuScenesMap, node_tokens: list[str]) -> np.ndarray:
    return np.array([[nmap.get("node", t)["x"], nmap.get("node", t)["y"]] for t in node_tokens])


def _by_av2_id(records: list[dict]) -> dict[int, dict]:
    return {r["av2_id"]: r for r in records}


def _one_way(a, b) -> float:
    pts = shapely.points(shapely.get_coordinates(shapely.segmentize(a, 0.05)))
    return float(shapely.distance(pts, b).max())


def _hausdorff(a, b) -> float:
    """Symmetric Hausdorff distance sampled every 5 cm along both geometries (never NaN)."""
    d = max(_one_way(a, b), _one_way(b, a))
    assert math.isfinite(d)
    return d


def test_devkit_loads_all_layers(written, av2_map):
    vm, frame, dataroot, art, nmap = written
    raw = json.loads((dataroot / art.expansion_path).read_text())
    assert set(LIST_LAYERS) | {"arcline_path_3", "connectivity", "version", "canvas_edge"} <= set(raw)
    assert raw["version"] >= "1.3" and min(raw["canvas_edge"]) > 0
    assert len(nmap.lane) + len(nmap.lane_connector) == len(av2_map.vector_lane_segments) == 199
    assert len(nmap.lane_connector) == sum(ls.is_intersection for ls in av2_map.vector_lane_segments.values())
    assert len(nmap.ped_crossing) == len(av2_map.vector_pedestrian_crossings) == 11
    assert len(nmap.drivable_area) == len(av2_map.vector_drivable_areas) == 8
    assert nmap.road_divider and nmap.lane_divider
    assert all(r["lane_type"] in ("CAR", "BIKE") for r in nmap.lane + nmap.lane_connector)
    assert art.stats["lanes_dropped"] == 0 and art.stats["polygons_repaired"] == 0
    # The true city coordinates stay recoverable.
    assert raw["nuav2"]["city_offset"] == frame.city_offset.tolist()
    nodes = np.array([[n["x"], n["y"]] for n in nmap.node])
    assert nodes.min() >= MARGIN_M - 1e-9
    assert np.all(nodes[:, 0] < raw["canvas_edge"][0]) and np.all(nodes[:, 1] < raw["canvas_edge"][1])


def test_city_global_round_trip(written):
    vm, frame, *_ = written
    back = to_global(vm, MapFrame(frame.location, -frame.city_offset))  # the inverse shift: global -> city
    again = to_global(to_global(vm, frame), MapFrame(frame.location, -frame.city_offset))
    for lane_id, lane in vm.lane_segments.items():
        np.testing.assert_allclose(again.lane_segments[lane_id].left_boundary, lane.left_boundary, atol=1e-9)
        np.testing.assert_allclose(back.lane_segments[lane_id].right_boundary[:, :2],
                                   lane.right_boundary[:, :2] + frame.city_offset[:2], atol=1e-9)


def test_lane_boundaries_and_polygons_match_av2(written, av2_map):
    vm, frame, _, _, nmap = written
    off = frame.city_offset[:2]
    records = _by_av2_id(nmap.lane + nmap.lane_connector)
    worst = 0.0
    for lane_id, ls in av2_map.vector_lane_segments.items():
        rec = records[lane_id]
        left = _xy(nmap, [s["node_token"] for s in rec["left_lane_divider_segments"]]) + off
        right = _xy(nmap, [s["node_token"] for s in rec["right_lane_divider_segments"]]) + off
        for got, want in ((left, ls.left_lane_boundary.xyz), (right, ls.right_lane_boundary.xyz)):
            want_line = LineString(want[:, :2]) if len(want) > 1 else Point(want[0, :2])
            got_line = LineString(got) if len(got) > 1 else Point(got[0])
            worst = max(worst, _hausdorff(got_line, want_line))
        poly = nmap.explorer.extract_polygon(rec["polygon_token"])
        assert poly.is_valid
        want_poly = Polygon(av2_map.get_lane_segment_polygon(lane_id)[:, :2])
        worst = max(worst, _hausdorff(shapely.affinity.translate(poly.exterior, *off), want_poly.exterior))
    assert worst < CM


def test_crossings_and_drivable_areas_match_av2(written, av2_map):
    _, frame, _, _, nmap = written
    off = frame.city_offset[:2]
    crossings = _by_av2_id(nmap.ped_crossing)
    for cid, pc in av2_map.vector_pedestrian_crossings.items():
        poly = nmap.explorer.extract_polygon(crossings[cid]["polygon_token"])
        want = Polygon(pc.polygon[:, :2])
        assert _hausdorff(shapely.affinity.translate(poly.exterior, *off), want.exterior) < CM
    areas = _by_av2_id(nmap.drivable_area)
    for aid, da in av2_map.vector_drivable_areas.items():
        polys = [nmap.explorer.extract_polygon(t) for t in areas[aid]["polygon_tokens"]]
        assert len(polys) == 1 and polys[0].is_valid
        got = shapely.affinity.translate(polys[0].exterior, *off)
        assert _hausdorff(got, Polygon(da.xyz[:, :2]).exterior) < CM


def test_road_segments_cover_exactly_the_drivable_area(written):
    _, _, _, _, nmap = written
    drivable = shapely.unary_union([nmap.explorer.extract_polygon(t)
                                    for r in nmap.drivable_area for t in r["polygon_tokens"]])
    segments = shapely.unary_union([nmap.explorer.extract_polygon(r["polygon_token"])
                                    for r in nmap.road_segment])
    assert shapely.symmetric_difference(drivable, segments).area < 0.01
    assert any(r["is_intersection"] for r in nmap.road_segment)
    assert any(not r["is_intersection"] for r in nmap.road_segment)


def test_dividers_are_the_painted_boundaries_once(written, av2_map):
    _, frame, _, _, nmap = written
    off = frame.city_offset[:2]
    painted = [b.xyz[:, :2] - off for ls in av2_map.vector_lane_segments.values()
               for b, mark in ((ls.left_lane_boundary, ls.left_mark_type),
                               (ls.right_lane_boundary, ls.right_mark_type))
               if mark.value not in ("NONE", "UNKNOWN")]
    lines = {layer: [nmap.explorer.extract_line(r["line_token"]) for r in getattr(nmap, layer)]
             for layer in ("road_divider", "lane_divider")}
    all_lines = shapely.MultiLineString(lines["road_divider"] + lines["lane_divider"])
    painted_union = shapely.unary_union([LineString(p) for p in painted])
    # Every painted boundary lies on a divider and every divider on a painted boundary.
    assert max(all_lines.distance(Point(q)) for p in painted for q in densify(p, 0.5)[0]) < CM
    dense = [Point(q) for ln in all_lines.geoms for q in densify(np.asarray(ln.coords), 0.5)[0]]
    assert max(painted_union.distance(q) for q in dense) < CM
    # Shared boundaries are written once: total divider length equals the union's length.
    assert sum(ln.length for ln in all_lines.geoms) == pytest.approx(painted_union.length, abs=0.05)
    # Double yellow centre lines are road dividers; dashed white lane lines are lane dividers.
    road = shapely.unary_union(lines["road_divider"]).buffer(CM)
    for ls in av2_map.vector_lane_segments.values():
        if ls.left_mark_type.value == "DOUBLE_SOLID_YELLOW":
            assert road.covers(LineString(ls.left_lane_boundary.xyz[:, :2] - off))
        if ls.left_mark_type.value == "DASHED_WHITE":
            assert not road.covers(LineString(ls.left_lane_boundary.xyz[:, :2] - off))
    # Line nodes are dense enough for the devkit's node-only patch test.
    for r in nmap.road_divider + nmap.lane_divider:
        xy = _xy(nmap, r["node_tokens"])
        assert np.hypot(*np.diff(xy, axis=0).T).max() <= 1.0 + 1e-6


def test_centerlines_match_av2(written, av2_map):
    _, frame, _, _, nmap = written
    off = frame.city_offset[:2]
    records = _by_av2_id(nmap.lane + nmap.lane_connector)
    tokens = [r["token"] for r in records.values()]
    discretized = nmap.discretize_lanes(tokens, 0.5)
    from av2.geometry.interpolate import compute_midpoint_line

    for lane_id, ls in av2_map.vector_lane_segments.items():
        poses = np.asarray(discretized[records[lane_id]["token"]])
        assert len(poses) >= 2 and np.all(np.isfinite(poses))
        ours = LineString(poses[:, :2] + off)
        left, right = ls.left_lane_boundary.xyz, ls.right_lane_boundary.xyz
        length = max(LineString(left).length, LineString(right).length)
        n = max(MIN_CENTERLINE_POINTS, math.ceil(length / CENTERLINE_SPACING_M) + 1)
        if len(left) > 1 and len(right) > 1:
            same_density, _ = compute_midpoint_line(left, right, n)
            assert _hausdorff(ours, LineString(same_density[:, :2])) < CM
        # av2's own 10-point centerline vertices lie on ours up to our 1 m sampling of the boundaries
        # (the chords between them cut curves by up to 0.7 m on this map; ours follows the curve).
        av2_pts = av2_map.get_lane_segment_centerline(lane_id)[:, :2]
        assert max(ours.distance(Point(p)) for p in av2_pts) < 5 * CM
        np.testing.assert_allclose(poses[0, :2] + off, av2_pts[0], atol=CM)
        np.testing.assert_allclose(poses[-1, :2] + off, av2_pts[-1], atol=CM)


def test_connectivity_is_inverted_successors(written, av2_map):
    _, _, _, _, nmap = written
    token = {r["av2_id"]: r["token"] for r in nmap.lane + nmap.lane_connector}
    lanes = av2_map.vector_lane_segments
    assert set(nmap.connectivity) == set(token.values())
    for lane_id, ls in lanes.items():
        want_out = {token[s] for s in ls.successors if s in lanes}
        want_in = {token[p] for p, other in lanes.items() if lane_id in other.successors}
        assert set(nmap.get_outgoing_lane_ids(token[lane_id])) == want_out
        assert set(nmap.get_incoming_lane_ids(token[lane_id])) == want_in
    # AV2's own predecessor lists miss links that inverted successors recover.
    n_pred = sum(len([p for p in ls.predecessors if p in lanes]) for ls in lanes.values())
    assert sum(len(c["incoming"]) for c in nmap.connectivity.values()) > n_pred


def test_every_polygon_valid(written):
    _, _, _, _, nmap = written
    for rec in nmap.polygon:
        poly = nmap.explorer.extract_polygon(rec["token"])
        assert poly.is_valid and poly.area > 0, rec["token"]


def test_explorer_queries_and_rendering(written, tmp_path):
    _, _, dataroot, art, nmap = written
    lane = nmap.lane[0]
    cx, cy = np.asarray(nmap.discretize_lanes([lane["token"]], 1.0)[lane["token"]])[2, :2]
    geom = dict(nmap.get_map_geom((cx, cy, 60.0, 30.0), 37.0,
                                  ["drivable_area", "road_segment", "lane", "ped_crossing", "road_divider",
                                   "lane_divider"]))
    assert geom["drivable_area"] and geom["lane"]
    assert all(not g.is_empty for g in geom["lane"])
    found = nmap.get_records_in_patch((cx - 30, cy - 30, cx + 30, cy + 30), ["lane", "lane_connector"])
    assert lane["token"] in found["lane"]
    # A 2 m patch on a divider's middle finds it (line nodes are densified).
    div = nmap.lane_divider[0]
    line = nmap.explorer.extract_line(div["line_token"])
    mx, my = line.interpolate(0.5, normalized=True).coords[0]
    hit = nmap.get_records_in_patch((mx - 1, my - 1, mx + 1, my + 1), ["lane_divider"])
    assert div["token"] in hit["lane_divider"]
    masks = nmap.get_map_mask((cx, cy, 60.0, 30.0), 37.0, ["drivable_area", "lane_divider"], (200, 100))
    assert masks.shape == (2, 200, 100) and masks[0].any()
    whole = nmap.get_map_mask(None, 0.0, ["drivable_area"], None)
    assert whole.shape[1:] == art.mask_shape
    bitmap = BitMap(str(dataroot), nmap.map_name, "semantic_prior")
    assert bitmap.image.shape == art.mask_shape
    fig, _ = nmap.render_map_patch((cx - 40, cy - 40, cx + 40, cy + 40), figsize=(4, 4), bitmap=bitmap)
    out = tmp_path / "patch.png"
    fig.savefig(out)
    matplotlib.pyplot.close(fig)
    assert out.stat().st_size > 5000


def test_mask_is_the_drivable_area(written, poses_xy_city):
    _, frame, dataroot, art, nmap = written
    mm = MapMask(str(dataroot / art.mask_filename), resolution=0.1)
    drivable = shapely.unary_union([nmap.explorer.extract_polygon(t)
                                    for r in nmap.drivable_area for t in r["polygon_tokens"]])
    rng = np.random.default_rng(0)
    pts = rng.uniform([0, 0], art.canvas_edge, size=(4000, 2))
    inside = shapely.contains_xy(drivable, pts[:, 0], pts[:, 1])
    # MapMask answers for the pixel whose centre is nearest: at most half a pixel diagonal away
    far = np.array([drivable.boundary.distance(Point(p)) > 0.05 * np.sqrt(2) + 1e-6 for p in pts])
    on = mm.is_on_mask(pts[:, 0], pts[:, 1])
    assert inside[far].any() and (~inside[far]).any()
    np.testing.assert_array_equal(on[far], inside[far])
    # The poses fall inside the image, and all driving happens on the prior.
    pose_g = frame.city_to_global_xy(poses_xy_city)
    px, py = mm.to_pixel_coords(pose_g[:, 0], pose_g[:, 1])
    assert px.min() >= 0 and py.min() >= 0 and px.max() < art.mask_shape[1] and py.max() < art.mask_shape[0]
    assert mm.is_on_mask(pose_g[:, 0], pose_g[:, 1], dilation=1.0).mean() > 0.99


def test_output_is_deterministic(written, tmp_path):
    vm, frame, *_ = written
    first = write_map_expansion(vm, frame, tmp_path / "a")
    write_map_expansion(vm, frame, tmp_path / "b")
    for rel in (first.expansion_path, first.mask_filename):
        assert (tmp_path / "a" / rel).read_bytes() == (tmp_path / "b" / rel).read_bytes()


# ---------------------------------------------------------------- building blocks


@settings(max_examples=30, deadline=None)
@given(st.lists(st.tuples(st.floats(20.0, 400.0), st.floats(20.0, 400.0)), min_size=2, max_size=6),
       st.floats(0.2, 2.0))
def test_straight_arclines_reproduce_polyline_in_devkit(vertices, resolution_m):
    xy = np.round(np.array(vertices), 4)
    keep = np.concatenate([[True], np.hypot(*np.diff(xy, axis=0).T) > 0.01])
    xy = xy[keep]
    pieces = straight_arcline_pieces(xy)
    assert len(pieces) == len(xy) - 1
    poses = np.asarray(discretize_lane(pieces, resolution_m))
    if len(xy) < 2:
        assert len(poses) == 0
        return
    assert np.all(np.isfinite(poses))
    assert shapely.distance(LineString(xy), shapely.points(poses[:, :2])).max() < 1e-6
    for v in xy:  # every vertex is reproduced exactly
        assert np.hypot(*(poses[:, :2] - v).T).min() < 1e-6
    steps = np.hypot(*np.diff(poses[:, :2], axis=0).T)
    assert steps.max() <= resolution_m + 1e-6


def test_resample_and_centerline_oracles():
    line = np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0], [10.0, 10.0, 0.0]])
    pts = resample_by_arclength(line, 5)
    np.testing.assert_allclose(pts[:, :2], [[0, 0], [5, 0], [10, 0], [10, 5], [10, 10]], atol=1e-12)
    np.testing.assert_array_equal(resample_by_arclength(np.array([[3.0, 4.0], [3.0, 4.0]]), 3), [[3, 4]] * 3)
    left = np.array([[0.0, 1.0, 0.0], [30.0, 1.0, 0.0]])
    right = np.array([[0.0, -1.0, 0.0], [12.0, -1.0, 0.0], [30.0, -1.0, 0.0]])
    center = centerline_from_boundaries(left, right)
    assert len(center) == 31
    np.testing.assert_allclose(center[:, 1], 0.0, atol=1e-12)
    np.testing.assert_allclose(np.diff(center[:, 0]), 1.0, atol=1e-12)


def test_densify_keeps_geometry():
    xy = np.array([[0.0, 0.0], [3.5, 0.0], [3.5, 0.2], [0.0, 7.0]])
    dense, src = densify(xy, 1.0)
    assert np.hypot(*np.diff(dense, axis=0).T).max() <= 1.0 + 1e-12
    assert _hausdorff(LineString(dense), LineString(xy)) < 1e-9
    np.testing.assert_array_equal(dense[np.r_[0, np.flatnonzero(np.diff(src)) + 1]], xy)
    assert polyline_length(dense) == pytest.approx(polyline_length(xy))


def _lane(lane_id, left, right, succ=(), inter=False, lm="NONE", rm="NONE", ln=None, rn=None) -> LaneSegment:
    def z(a):
        a = np.asarray(a, dtype=np.float64).reshape(-1, 2)
        return np.concatenate([a, np.zeros((len(a), 1))], axis=1)

    return LaneSegment(lane_id, z(left), z(right), lm, rm, inter, "VEHICLE", tuple(succ), (), ln, rn)


def test_dividers_dedup_classify_and_chain():
    yellow, white = "DOUBLE_SOLID_YELLOW", "DASHED_WHITE"
    lanes = [
        # Eastbound 1 -> 4, with 3 to its right; westbound 2 -> 5 opposite, sharing the yellow line.
        _lane(1, [[0, 0], [10, 0]], [[0, -3], [10, -3]], succ=[4], lm=yellow, rm=white, ln=2, rn=3),
        _lane(4, [[10, 0], [20, 0]], [[10, -3], [20, -3]], lm=yellow, ln=5),
        _lane(3, [[0, -3], [10, -3]], [[0, -6], [10, -6]], lm=white, ln=1),
        _lane(2, [[10, 0], [0, 0]], [[10, 3], [0, 3]], lm=yellow, ln=1),
        _lane(5, [[20, 0], [10, 0]], [[20, 3], [10, 3]], succ=[2], lm=yellow, ln=4),
    ]
    dividers = extract_dividers(lanes)
    road = [d for d in dividers if d.layer == "road_divider"]
    lane_div = [d for d in dividers if d.layer == "lane_divider"]
    assert len(road) == 1 and len(lane_div) == 1
    assert LineString(road[0].xy).equals(LineString([[0, 0], [20, 0]]))  # chained across 1 -> 4
    assert LineString(lane_div[0].xy).equals(LineString([[0, -3], [10, -3]]))  # shared by 1 and 3, once
    assert len(road[0].segment_types) == len(road[0].xy)
    assert {s[0] for s in road[0].sources} == {1, 2, 4, 5}


# ---------------------------------------------------------------- hard cases, through the devkit


def _write_and_load(vm: VectorMap, tmp_path: Path, offset=(0.0, 0.0)):
    frame = MapFrame("av2-pit-0badc0de", np.array([*offset, 0.0], dtype=np.float64))
    art = write_map_expansion(vm, frame, tmp_path)
    nmap = NuScenesMap(str(tmp_path), map_name=frame.location)
    for rec in nmap.polygon:
        assert nmap.explorer.extract_polygon(rec["token"]).is_valid
    for pieces in nmap.arcline_path_3.values():
        assert all(math.isfinite(v) for p in pieces for v in p["start_pose"] + p["segment_length"])
    return art, nmap


def test_empty_map(tmp_path):
    art, nmap = _write_and_load(VectorMap("PIT", {}, {}, {}), tmp_path)
    assert all(len(getattr(nmap, layer)) == 0 for layer in LIST_LAYERS)
    edge = 2 * MARGIN_M
    assert nmap.canvas_edge == [edge, edge] and art.mask_shape == (int(edge * 10), int(edge * 10))
    mm = MapMask(str(tmp_path / art.mask_filename))
    assert not mm.mask().any()
    assert all(not geoms for _, geoms in nmap.get_map_geom((20, 20, 10, 10), 0, ["drivable_area", "lane"]))
    assert nmap.get_map_mask(None, 0.0, ["drivable_area"], None).shape == (1, *art.mask_shape)
    fig, _ = nmap.render_map_patch((0, 0, 40, 40), figsize=(2, 2), render_legend=False)
    matplotlib.pyplot.close(fig)


def test_zero_length_polylines(tmp_path):
    p = [[40.0, 30.0]] * 2
    lanes = {
        1: _lane(1, [[20, 33], [40, 33]], [[20, 30], [40, 30]], succ=[9], rm="SOLID_WHITE"),
        9: _lane(9, [[40, 33], [40, 33]], p, succ=[2], lm="SOLID_WHITE", rm="SOLID_WHITE"),  # zero length
        2: _lane(2, [[40, 33], [60, 33]], [[40, 30], [60, 30]], succ=[777]),  # 777 is off the map
        3: _lane(3, [[60, 30]], [[60, 33], [65, 31.5], [60, 30.2]]),  # one-point boundary: a fan
    }
    point_edge = np.array([[30.0, 30, 0], [30, 30, 0]])
    crossings = {5: PedCrossing(5, point_edge, point_edge.copy())}
    areas = {7: DrivableArea(7, np.array([[20.0, 25, 0], [70, 25, 0], [70, 40, 0], [20, 40, 0]])),
             8: DrivableArea(8, np.array([[25.0, 25, 0]] * 3))}
    art, nmap = _write_and_load(VectorMap("PIT", lanes, crossings, areas), tmp_path)
    assert art.stats["lanes_dropped"] == 1 and art.stats["crossings_dropped"] == 1
    assert art.stats["drivable_areas_dropped"] == 1
    token = {r["av2_id"]: r["token"] for r in nmap.lane}
    assert set(token) == {1, 2, 3}
    assert nmap.get_outgoing_lane_ids(token[1]) == [token[2]]  # bridged across the dropped lane
    assert nmap.get_incoming_lane_ids(token[2]) == [token[1]]
    assert nmap.get_outgoing_lane_ids(token[2]) == []  # dangling id dropped
    fan = np.asarray(nmap.discretize_lanes([token[3]], 0.5)[token[3]])
    assert len(fan) >= 2 and polyline_length(fan[:, :2]) > 1.0
    assert not nmap.ped_crossing


def test_self_intersecting_polygons(tmp_path):
    lanes = {1: _lane(1, [[60, 30], [80, 32]], [[60, 32], [80, 30]])}  # boundaries cross: a bow-tie ring
    crossings = {4: PedCrossing(4, np.array([[30.0, 60, 0], [40, 60, 0]]),
                                np.array([[40.0, 64, 0], [30, 64, 0]]))}  # edge2 reversed
    areas = {7: DrivableArea(7, np.array([[30.0, 30, 0], [50, 50, 0], [50, 30, 0], [30, 50, 0]]))}
    art, nmap = _write_and_load(VectorMap("PIT", lanes, crossings, areas), tmp_path)
    assert art.stats["polygons_repaired"] >= 2
    pieces = [nmap.explorer.extract_polygon(t) for t in nmap.drivable_area[0]["polygon_tokens"]]
    assert len(pieces) == 2 and sum(p.area for p in pieces) == pytest.approx(200.0)
    lane_poly = nmap.explorer.extract_polygon(nmap.lane[0]["polygon_token"])
    assert lane_poly.area == pytest.approx(20.0, rel=0.02)
    crossing = nmap.explorer.extract_polygon(nmap.ped_crossing[0]["polygon_token"])
    assert crossing.area == pytest.approx(40.0)
    geom = dict(nmap.get_map_geom((50, 50, 80, 80), 0.0, ["lane", "ped_crossing", "drivable_area"]))
    assert len(geom["lane"]) == 1 and len(geom["ped_crossing"]) == 1 and len(geom["drivable_area"]) == 2


def test_bad_input_is_refused():
    lane = _lane(1, [[20, 33], [40, 33]], [[20, 30], [40, 30]])
    vm = VectorMap("PIT", {1: lane}, {}, {})
    with pytest.raises(ValueError, match="does not match"):
        build_map_expansion(vm, MapFrame("pittsburgh", np.zeros(3)))
    with pytest.raises(ValueError, match="< 0"):
        build_map_expansion(vm, MapFrame("av2-pit-0badc0de", np.array([25.0, 0.0, 0.0])))
    nan_lane = _lane(2, [[20, np.nan], [40, 33]], [[20, 30], [40, 30]])
    with pytest.raises(ValueError, match="lane 2 boundary has NaN"):
        build_map_expansion(VectorMap("PIT", {2: nan_lane}, {}, {}),
                            MapFrame("av2-pit-0badc0de", np.zeros(3)))


# ---------------------------------------------------------------- devkit compatibility shim


def test_devkit_compat_admits_only_av2_locations(tmp_path):
    from nuscenes.map_expansion import map_api

    assert "av2-pit-adcf7d18" in map_api.locations and "boston-seaport" in map_api.locations
    assert "austin" not in map_api.locations and "av2-pit-ADCF7D18" not in map_api.locations
    assert list(map_api.locations) == ["singapore-onenorth", "singapore-hollandvillage",
                                       "singapore-queenstown", "boston-seaport"]
    with pytest.raises(AssertionError, match="Unknown map name"):
        NuScenesMap(str(tmp_path), map_name="austin")


def test_devkit_compat_patches_an_already_imported_devkit():
    import subprocess
    import sys

    code = (
        "import matplotlib; matplotlib.use('Agg')\n"
        "import descartes.patch, nuscenes.map_expansion.map_api as m, nuscenes.map_expansion.bitmap as b\n"
        "import nuav2.devkit_compat\n"
        "assert 'av2-sfo-01234567' in m.locations\n"
        "assert m.NuScenesMapExplorer.get_map_mask._nuav2_patched and b.BitMap.load_bitmap._nuav2_patched\n"
        "from shapely.geometry import box\n"
        "path = descartes.patch.PolygonPath(box(0, 0, 1, 1).difference(box(0.2, 0.2, 0.4, 0.4)))\n"
        "assert len(path.vertices) == 10\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)
