"""Vectorized map GT: patch frame, protocol geometry steps, and the devkit-backed vectorizer.

The vectorizer is checked on a hand-made map expansion loaded by the real devkit
``NuScenesMap``: against the devkit explorer's own ``get_map_geom`` cut, and against the
polylines the protocol must produce for a known road.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from shapely.geometry import LineString, Polygon, box

from nuav2.geometry import T_from_quat_trans, T_inverse, make_T, rot_to_quat, transform_points
from nuav2.maptr.fixed_points import is_closed
from nuav2.maptr.vectorize import (
    LocalMapVectorizer,
    MapGT,
    MapPatch,
    centerline_paths,
    contour_lines,
    split_lines,
)

# ------------------------------------------------------------------ patch frame


def _rot_z(yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


@pytest.mark.parametrize("yaw", [0.0, 0.7, -math.pi / 2, math.pi, 3.0])
def test_patch_local_frame_is_the_lidar_frame_for_a_level_lidar(yaw):
    global_T_lidar = make_T(_rot_z(yaw), [4321.5, 1234.25, 1.84])
    patch = MapPatch.from_pose(global_T_lidar)
    rng = np.random.default_rng(0)
    pts_global = np.column_stack(
        [rng.uniform(4000, 4600, 50), rng.uniform(1000, 1500, 50), np.full(50, 1.84)]
    )
    oracle = transform_points(T_inverse(global_T_lidar), pts_global)[:, :2]
    np.testing.assert_allclose(patch.global_to_local_xy(pts_global[:, :2]), oracle, atol=1e-9)
    np.testing.assert_allclose(patch.local_to_global_xy(oracle), pts_global[:, :2], atol=1e-9)


def test_patch_is_60_forward_by_30_right_of_a_nuscenes_lidar():
    # ego heading +x (east); nuScenes LIDAR_TOP yawed -90 deg: lidar x = ego right, lidar y = forward
    ego_T_lidar = T_from_quat_trans(
        [0.7077955119163518, -0.006492242056004365, 0.010646214713995808, -0.7063073142877817],
        [0.943713, 0.0, 1.84023],
    )
    global_T_lidar = make_T(np.eye(3), [500.0, 800.0, 0.0]) @ ego_T_lidar
    patch = MapPatch.from_pose(global_T_lidar)
    minx, miny, maxx, maxy = patch.polygon().bounds
    assert maxx - minx == pytest.approx(60.0, abs=0.2) and maxy - miny == pytest.approx(30.0, abs=0.2)
    ahead = patch.global_to_local_xy(np.array([[500.0 + 0.943713 + 10.0, 800.0]]))[0]
    assert ahead == pytest.approx([0.0, 10.0], abs=0.05)  # 10 m ahead -> +y
    right = patch.global_to_local_xy(np.array([[500.0 + 0.943713, 800.0 - 5.0]]))[0]
    assert right == pytest.approx([5.0, 0.0], abs=0.05)  # 5 m right -> +x


def test_patch_uses_yaw_only_when_the_lidar_is_tilted():
    R = _rot_z(0.3) @ np.array(
        [[1, 0, 0], [0, math.cos(0.05), -math.sin(0.05)], [0, math.sin(0.05), math.cos(0.05)]]
    )
    patch = MapPatch.from_pose(make_T(R, [10.0, 20.0, 3.0]))
    assert patch.yaw == pytest.approx(0.3, abs=1e-12)


def test_patch_rejects_bad_poses():
    with pytest.raises(ValueError, match="finite"):
        MapPatch.from_pose(np.full((4, 4), np.nan))
    with pytest.raises(ValueError, match="positive"):
        MapPatch.from_pose(np.eye(4), (0.0, 30.0))


# ------------------------------------------------------------------ protocol geometry steps


def test_split_lines_flattens_and_drops_degenerate_parts():
    from shapely.geometry import GeometryCollection, MultiLineString, Point

    geoms = [
        MultiLineString([[(0, 0), (1, 0)], [(2, 0), (3, 0)]]),
        GeometryCollection([Point(5, 5), LineString([(0, 1), (0, 2)])]),
        LineString([(1, 1), (1, 1)]),
        LineString(),
    ]
    out = split_lines(geoms)
    assert [list(g.coords) for g in out] == [[(0, 0), (1, 0)], [(2, 0), (3, 0)], [(0, 1), (0, 2)]]


def test_crossing_ring_stays_closed_and_clockwise_when_grown_patch_clips_nothing():
    ccw_square = Polygon([(0, 0), (4, 0), (4, 2), (0, 2)])
    lines = contour_lines([ccw_square], (15.0, 30.0), +0.2)
    assert len(lines) == 1 and is_closed(np.asarray(lines[0].coords))
    from shapely.geometry import LinearRing

    assert not LinearRing(lines[0].coords).is_ccw


def test_overlapping_crossings_are_unioned_into_one_ring():
    a = Polygon([(0, 0), (4, 0), (4, 2), (0, 2)])
    b = Polygon([(3, 0), (8, 0), (8, 2), (3, 2)])
    lines = contour_lines([a, b], (15.0, 30.0), +0.2)
    assert len(lines) == 1 and Polygon(lines[0].coords).area == pytest.approx(16.0)


def test_boundary_drops_the_patch_edge_and_keeps_road_edges_open():
    # road crossing the whole patch along y, already clipped to it: x in [-10, 10], y in [-30, 30]
    road = box(-10, -30, 10, 30)
    lines = contour_lines([road], (15.0, 30.0), -0.2)
    assert len(lines) == 2
    for line in lines:
        xy = np.asarray(line.coords)
        assert np.allclose(np.abs(xy[:, 0]), 10.0)  # only the road edges remain
        assert xy[:, 1].min() == pytest.approx(-29.8) and xy[:, 1].max() == pytest.approx(29.8)
    # clockwise exterior: the right edge (x = +10) runs towards -y
    right = next(ln for ln in lines if ln.coords[0][0] > 0)
    assert right.coords[0][1] > right.coords[-1][1]


def test_boundary_hole_is_a_closed_counter_clockwise_ring():
    from shapely.geometry import LinearRing

    road = Polygon(box(-10, -30, 10, 30).exterior.coords, [box(-2, -5, 2, 5).exterior.coords])
    lines = contour_lines([road], (15.0, 30.0), -0.2)
    rings = [ln for ln in lines if is_closed(np.asarray(ln.coords))]
    assert len(rings) == 1 and LinearRing(rings[0].coords).is_ccw


def test_ring_cut_at_its_start_vertex_is_merged_back():
    # a U-shaped road whose outline's start vertex is in the middle of a kept piece
    u = Polygon([(0, -40), (5, -40), (5, 10), (-5, 10), (-5, -40), (-1, -40), (-1, 5), (0, 5)])
    lines = contour_lines([u.intersection(box(-15, -30, 15, 30))], (15.0, 30.0), -0.2)
    assert len(lines) == 2  # the outer and inner outline pieces, each one line
    assert sum(ln.length for ln in lines) == pytest.approx(
        (29.8 + 10) * 2 + 10 + (29.8 + 5) * 2 + 1, abs=1e-6
    )


def test_empty_inputs_give_no_lines():
    assert contour_lines([], (15.0, 30.0), 0.2) == []
    assert contour_lines([Polygon()], (15.0, 30.0), 0.2) == []
    assert centerline_paths({}, []) == []


def test_centerlines_chain_through_links_and_fork():
    pieces = {
        "a": [np.array([[0.0, -30.0], [0.0, 0.0]])],
        "b": [np.array([[0.0, 0.0], [0.0, 30.0]])],  # straight on
        "c": [np.array([[0.0, 0.0], [5.0, 5.0], [10.0, 8.0]])],  # turn right
        "d": [np.array([[-5.0, 30.0], [-5.0, -30.0]])],  # unrelated opposite lane
    }
    links = [("a", "b"), ("a", "c"), ("x", "a")]  # "x" is outside the patch: ignored
    paths = centerline_paths(pieces, links, simplify_m=0.0)
    coords = sorted(tuple(map(tuple, np.asarray(p.coords))) for p in paths)
    assert coords == sorted(
        [
            ((0.0, -30.0), (0.0, 0.0), (0.0, 30.0)),
            ((0.0, -30.0), (0.0, 0.0), (5.0, 5.0), (10.0, 8.0)),
            ((-5.0, 30.0), (-5.0, -30.0)),
        ]
    )


def test_centerline_gap_between_lanes_is_bridged_and_simplified():
    straight = np.column_stack([np.zeros(61), np.linspace(-30, 0, 61)])
    nxt = np.column_stack([np.zeros(20) + 0.0004, np.linspace(0.5, 30, 20)])
    paths = centerline_paths({"a": [straight], "b": [nxt]}, [("a", "b")], simplify_m=0.2)
    assert len(paths) == 1
    xy = np.asarray(paths[0].coords)
    assert len(xy) == 2 and xy[0][1] == -30.0 and xy[-1][1] == 30.0  # simplified to its two ends


def test_centerline_mm_rounding_joins_nearly_equal_ends():
    a = np.array([[0.0, -10.0], [0.0, 0.0001]])
    b = np.array([[0.0002, 0.0], [0.0, 10.0]])
    paths = centerline_paths({"a": [a], "b": [b]}, [], simplify_m=0.0)
    assert len(paths) == 1 and paths[0].length == pytest.approx(20.0, abs=1e-3)


def test_centerline_path_explosion_is_capped():
    # a ladder of 12 binary forks has 2**12 paths
    pieces, links = {}, []
    for i in range(12):
        pieces[f"l{i}"] = [np.array([[0.0, 2.0 * i], [-0.5, 2.0 * i + 1.0], [0.0, 2.0 * i + 2.0]])]
        pieces[f"r{i}"] = [np.array([[0.0, 2.0 * i], [0.5, 2.0 * i + 1.0], [0.0, 2.0 * i + 2.0]])]
    paths = centerline_paths(pieces, links, simplify_m=0.0, max_paths=100)
    assert len(paths) == 100


# ------------------------------------------------------------------ devkit-backed vectorizer

LOCATION = "boston-seaport"  # a name the unmodified devkit accepts; the content is hand-made


class _MapBuilder:
    def __init__(self):
        self.layers = {
            k: []
            for k in (
                "polygon",
                "line",
                "node",
                "drivable_area",
                "road_segment",
                "road_block",
                "lane",
                "ped_crossing",
                "walkway",
                "stop_line",
                "carpark_area",
                "road_divider",
                "lane_divider",
                "traffic_light",
                "lane_connector",
            )
        }
        self.arclines: dict[str, list] = {}
        self.connectivity: dict[str, dict] = {}
        self._n = 0

    def _tok(self, prefix: str) -> str:
        self._n += 1
        return f"{prefix}-{self._n:04d}"

    def _nodes(self, xy) -> list[str]:
        toks = []
        for x, y in xy:
            t = self._tok("node")
            self.layers["node"].append({"token": t, "x": float(x), "y": float(y)})
            toks.append(t)
        return toks

    def polygon(self, xy, holes=()) -> str:
        t = self._tok("polygon")
        self.layers["polygon"].append(
            {
                "token": t,
                "exterior_node_tokens": self._nodes(xy),
                "holes": [{"node_tokens": self._nodes(h)} for h in holes],
            }
        )
        return t

    def line(self, layer: str, xy) -> str:
        lt = self._tok("line")
        self.layers["line"].append({"token": lt, "node_tokens": self._nodes(xy)})
        t = self._tok(layer)
        self.layers[layer].append({"token": t, "line_token": lt})
        return t

    def area(self, layer: str, xy) -> str:
        t = self._tok(layer)
        self.layers[layer].append({"token": t, "polygon_token": self.polygon(xy)})
        return t

    def lane(self, xy_poly, centerline, layer: str = "lane") -> str:
        t = self._tok(layer)
        rec = {"token": t, "polygon_token": self.polygon(xy_poly)}
        if layer == "lane":
            rec.update(lane_type="CAR", left_lane_divider_segments=[], right_lane_divider_segments=[])
        self.layers[layer].append(rec)
        pieces = []
        for (x0, y0), (x1, y1) in zip(centerline[:-1], centerline[1:]):
            yaw = math.atan2(y1 - y0, x1 - x0)
            pieces.append(
                {
                    "start_pose": [x0, y0, yaw],
                    "end_pose": [x1, y1, yaw],
                    "shape": "LSL",
                    "radius": 999.0,
                    "segment_length": [0.0, math.hypot(x1 - x0, y1 - y0), 0.0],
                }
            )
        self.arclines[t] = pieces
        self.connectivity[t] = {"incoming": [], "outgoing": []}
        return t

    def link(self, a: str, b: str) -> None:
        self.connectivity[a]["outgoing"].append(b)
        self.connectivity[b]["incoming"].append(a)

    def write(self, dataroot: Path) -> None:
        obj = dict(
            self.layers,
            version="1.3",
            canvas_edge=[400.0, 300.0],
            arcline_path_3=self.arclines,
            connectivity=self.connectivity,
        )
        (dataroot / "maps" / "expansion").mkdir(parents=True, exist_ok=True)
        (dataroot / "maps" / "expansion" / f"{LOCATION}.json").write_text(json.dumps(obj))


@pytest.fixture(scope="module")
def straight_road(tmp_path_factory) -> Path:
    """Two-way road along +x at y in [90, 110] (eastbound lanes below y = 100), a crossing at x 120-124,
    a bow-tie (self-intersecting) crossing the devkit must drop, and a divider line whose nodes all lie
    outside the patch."""
    m = _MapBuilder()
    m.area("road_segment", [(0, 90), (200, 90), (200, 110), (0, 110)])
    east_a = m.lane([(0, 90), (100, 90), (100, 100), (0, 100)], [(0, 95), (100, 95)])
    east_b = m.lane([(100, 90), (200, 90), (200, 100), (100, 100)], [(100, 95), (200, 95)])
    m.lane([(0, 100), (200, 100), (200, 110), (0, 110)], [(200, 105), (0, 105)])
    m.link(east_a, east_b)
    m.line("lane_divider", [(0, 100), (200, 100)])
    m.area("ped_crossing", [(120, 90), (124, 90), (124, 110), (120, 110)])
    m.area("ped_crossing", [(60, 90), (64, 110), (64, 90), (60, 110)])  # bow-tie: invalid
    m.line("road_divider", [(50, 92), (150, 92)])  # both nodes outside the 60 m patch around x = 100
    root = tmp_path_factory.mktemp("handmade_map")
    m.write(root)
    return root


def _nusc_map(root: Path):
    from nuscenes.map_expansion.map_api import NuScenesMap

    return NuScenesMap(dataroot=str(root), map_name=LOCATION)


def _lidar_pose(x: float, y: float, ego_yaw: float) -> np.ndarray:
    """nuScenes-like LIDAR_TOP (yaw -90 deg in the ego frame) on an ego at (x, y, ego_yaw)."""
    return make_T(_rot_z(ego_yaw), [x, y, 0.0]) @ make_T(_rot_z(-math.pi / 2), [0.0, 0.0, 1.84])


def _by_class(vectors):
    out: dict[str, list[np.ndarray]] = {}
    for cls, pts in vectors:
        out.setdefault(cls, []).append(pts)
    return out


def test_known_road_gives_the_protocol_vectors(straight_road):
    vec = LocalMapVectorizer(_nusc_map(straight_road))
    assert vec.dropped_invalid == {"ped_crossing": 1}
    got = _by_class(vec.vectors(MapPatch.from_pose(_lidar_pose(100.0, 100.0, 0.0))))
    assert set(got) == {"divider", "ped_crossing", "boundary", "centerline"}
    # dividers: lane divider on the lidar y-axis, full patch length; the node-less-in-patch road divider too
    div = sorted(got["divider"], key=lambda p: p[0, 0])
    assert len(div) == 2
    np.testing.assert_allclose(div[0][:, 0], 0.0, atol=1e-9)
    np.testing.assert_allclose(sorted(div[0][:, 1]), [-30.0, 30.0], atol=1e-9)
    np.testing.assert_allclose(div[1][:, 0], 8.0, atol=1e-9)  # y = 92 is 8 m right of the lidar
    # crossing: one closed ring covering x in [-10, 10], y in [20, 24]
    (ped,) = got["ped_crossing"]
    assert is_closed(ped) and Polygon(ped).area == pytest.approx(80.0)
    np.testing.assert_allclose(
        [ped[:, 0].min(), ped[:, 0].max(), ped[:, 1].min(), ped[:, 1].max()], [-10, 10, 20, 24], atol=1e-9
    )
    # boundary: the two road edges at x = +-10, cut 0.2 m inside the patch
    assert len(got["boundary"]) == 2
    for b in got["boundary"]:
        np.testing.assert_allclose(np.abs(b[:, 0]), 10.0, atol=1e-9)
        assert b[:, 1].min() == pytest.approx(-29.8) and b[:, 1].max() == pytest.approx(29.8)
    # centerlines: eastbound lanes a+b chained into one forward path at x = +5, westbound at x = -5 backwards
    cl = sorted(got["centerline"], key=lambda p: p[0, 0])
    assert len(cl) == 2
    np.testing.assert_allclose(cl[0], [[-5.0, 30.0], [-5.0, -30.0]], atol=1e-3)
    np.testing.assert_allclose(cl[1], [[5.0, -30.0], [5.0, 30.0]], atol=1e-3)


@pytest.mark.parametrize("pose", [(100.0, 100.0, 0.0), (130.0, 96.0, 0.4), (40.0, 105.0, -2.5)])
def test_vectorizer_cut_equals_the_devkit_explorer_cut(straight_road, pose):
    nusc_map = _nusc_map(straight_road)
    vec = LocalMapVectorizer(nusc_map)
    patch = MapPatch.from_pose(_lidar_pose(*pose))
    patch_box = (patch.center_xy[0], patch.center_xy[1], patch.length_m, patch.width_m)
    angle_deg = math.degrees(patch.yaw)
    geom = dict(
        nusc_map.get_map_geom(
            patch_box, angle_deg, ["road_divider", "lane_divider", "ped_crossing", "road_segment", "lane"]
        )
    )
    got = _by_class(vec.vectors(patch))

    def same(a: list[np.ndarray], b: list[np.ndarray]):
        key = lambda p: tuple(np.round(p[0], 6))  # noqa: E731
        assert len(a) == len(b)
        for pa, pb in zip(sorted(a, key=key), sorted(b, key=key)):
            np.testing.assert_allclose(pa, pb, atol=1e-6)

    devkit_div = [np.asarray(g.coords) for g in split_lines(geom["road_divider"] + geom["lane_divider"])]
    same(got.get("divider", []), devkit_div)
    devkit_ped = [
        np.asarray(g.coords) for g in contour_lines(geom["ped_crossing"], patch.half_extent_xy, 0.2)
    ]
    same(got.get("ped_crossing", []), devkit_ped)
    devkit_bd = [
        np.asarray(g.coords)
        for g in contour_lines(geom["road_segment"] + geom["lane"], patch.half_extent_xy, -0.2)
    ]
    same(got.get("boundary", []), devkit_bd)


def test_missing_or_broken_map_file_names_the_file(tmp_path):
    gt = MapGT(tmp_path)
    with pytest.raises(FileNotFoundError, match="expansion"):
        gt.vectorizer(LOCATION)
    (tmp_path / "maps" / "expansion").mkdir(parents=True)
    (tmp_path / "maps" / "expansion" / f"{LOCATION}.json").write_text("{not json")
    with pytest.raises(ValueError, match=f"{LOCATION}.json"):
        gt.vectorizer(LOCATION)


def test_all_vectors_are_finite_and_inside_the_patch(straight_road):
    vec = LocalMapVectorizer(_nusc_map(straight_road))
    rng = np.random.default_rng(3)
    for _ in range(10):
        pose = (rng.uniform(-20, 220), rng.uniform(60, 140), rng.uniform(-math.pi, math.pi))
        for cls, pts in vec.vectors(MapPatch.from_pose(_lidar_pose(*pose))):
            assert pts.ndim == 2 and pts.shape[1] == 2 and len(pts) >= 2 and np.all(np.isfinite(pts))
            lim = 0.2 + 1e-6 if cls == "ped_crossing" else 1e-6
            assert np.all(np.abs(pts[:, 0]) <= 15 + lim) and np.all(np.abs(pts[:, 1]) <= 30 + lim), cls


def test_quaternion_pose_round_trip_used_by_the_patch():
    R = _rot_z(1.1)
    T = T_from_quat_trans(rot_to_quat(R), [1.0, 2.0, 3.0])
    assert MapPatch.from_pose(T).yaw == pytest.approx(1.1, abs=1e-12)


@pytest.mark.parametrize("seed", range(6))
def test_centerline_dfs_equals_networkx_all_simple_paths(seed):
    """Oracle: MapTRv2 builds a networkx DiGraph and calls all_simple_paths(G, root, leaves)."""
    import networkx as nx

    rng = np.random.default_rng(seed)
    grid = [(float(x), float(y)) for x in range(4) for y in range(4)]
    pieces, edges = {}, set()
    for k in range(14):  # random directed 2-point lanes on a 4x4 grid: forks, merges, cycles
        a, b = rng.choice(len(grid), 2, replace=False)
        pieces[f"t{k:02d}"] = [np.array([grid[a], grid[b]])]
        edges.add((grid[a], grid[b]))
    graph = nx.DiGraph()
    graph.add_edges_from(sorted(edges))
    roots = sorted(n for n, d in graph.in_degree() if d == 0)
    leaves = [n for n, d in graph.out_degree() if d == 0]
    expected = sorted(tuple(map(tuple, p)) for r in roots for p in nx.all_simple_paths(graph, r, leaves))
    assert expected  # the random graph has root-to-leaf paths
    got = sorted(
        tuple(map(tuple, np.asarray(ln.coords))) for ln in centerline_paths(pieces, [], simplify_m=0.0)
    )
    assert got == expected


def test_empty_map_gives_no_vectors(tmp_path):
    _MapBuilder().write(tmp_path)
    vec = LocalMapVectorizer(_nusc_map(tmp_path))
    assert vec.vectors(MapPatch.from_pose(_lidar_pose(10.0, 10.0, 0.3))) == []
    assert vec.map is None  # the devkit map is released once the geometry is extracted


def test_a_start_repeated_to_the_millimetre_stays_a_root():
    """Clipping can leave two first points that round to one node; unlike MapTRv2's converter (a
    self-loop there makes the node a non-root and drops its paths) the lane's path is kept."""
    pieces = {"a": [np.array([[0.0, 0.0], [0.0002, 0.0], [5.0, 0.0]])],
              "b": [np.array([[5.0, 0.0], [10.0, 0.0]])]}
    paths = centerline_paths(pieces, [("a", "b")], simplify_m=0.0)
    assert len(paths) == 1
    assert paths[0].coords[0] == (0.0, 0.0) and paths[0].coords[-1] == (10.0, 0.0)
