"""Synthetic world: config validation, road graph invariants, determinism, timeline, texture sampling."""

from __future__ import annotations

import json

import numpy as np
import pytest
from shapely.geometry import LineString

from nuav2.synth import SynthConfig, build_world, load_world
from nuav2.synth.road import (
    DASH_PERIOD,
    DRIVABLE_HALF,
    INTER_HALF,
    ROAD_HALF,
    arm_length_for,
    build_road_layout,
)
from nuav2.synth.texture import MAT, MATERIALS, draw_layer
from nuav2.synth.timeline import CAMERA_PHASE_NS, make_timeline
from nuav2.synth.world import EGO_ORIGIN_HEIGHT_M, WORLD_FILE, clear_world_cache

SMALL = SynthConfig(seconds=0.5, lidar_azimuth_steps=64)


def test_config_roundtrip_and_validation():
    cfg = SynthConfig(seconds=3.0, image_scale=0.25, n_parked=2)
    assert SynthConfig.from_dict(cfg.to_dict()) == cfg
    assert cfg.n_sweeps == 30
    with pytest.raises(ValueError, match="seconds"):
        SynthConfig(seconds=0.0)
    with pytest.raises(ValueError, match="city"):
        SynthConfig(city="XYZ")
    with pytest.raises(ValueError, match="n_moving"):
        SynthConfig(n_moving=-1)
    with pytest.raises(ValueError, match="unknown SynthConfig field.*bogus"):
        SynthConfig.from_dict({"bogus": 1}, "x.json")


@pytest.mark.parametrize("arm", [arm_length_for(20.0), arm_length_for(75.0), arm_length_for(200.0)])
def test_lane_graph_invariants(arm):
    layout = build_road_layout(arm)
    assert (layout.arm_length - INTER_HALF) % DASH_PERIOD == 0
    by_id = {ln.id: ln for ln in layout.lanes}
    for ln in layout.lanes:
        # Boundaries follow travel: the left boundary lies left of the direction of travel.
        travel = ln.left[1] - ln.left[0]
        offset = ln.left[0] - ln.right[0]
        assert travel[0] * offset[1] - travel[1] * offset[0] > 0, ln.id
        width = np.linalg.norm(offset)
        assert width == pytest.approx(3.5, abs=1e-9)
        for s in ln.successors:
            nxt = by_id[s]
            np.testing.assert_allclose(ln.left[-1], nxt.left[0], atol=1e-9)
            np.testing.assert_allclose(ln.right[-1], nxt.right[0], atol=1e-9)
            assert ln.id in nxt.predecessors
        for p in ln.predecessors:
            assert ln.id in by_id[p].successors
        if ln.right_neighbor_id is not None:  # same-direction neighbours share the boundary
            nb = by_id[ln.right_neighbor_id]
            assert nb.left_neighbor_id == ln.id
            np.testing.assert_allclose(ln.right, nb.left)
        if ln.left_neighbor_id is not None and not ln.is_intersection and ln.left_mark.endswith("YELLOW"):
            opp = by_id[ln.left_neighbor_id]  # opposite lanes: mutual left neighbours, reversed boundary
            assert opp.left_neighbor_id == ln.id
            np.testing.assert_allclose(ln.left, opp.left[::-1])
    marks = {m for ln in layout.lanes for m in (ln.left_mark, ln.right_mark)}
    assert marks == {"NONE", "DOUBLE_SOLID_YELLOW", "DASHED_WHITE", "SOLID_WHITE"}
    assert all(ln.left_mark == "NONE" for ln in layout.lanes if ln.is_intersection)
    assert sum(ln.is_intersection for ln in layout.lanes) == 16  # 4 x (2 straight + left + right)
    for cw in layout.crosswalks:
        d1, d2 = cw.edge1[1] - cw.edge1[0], cw.edge2[1] - cw.edge2[0]
        np.testing.assert_allclose(d1, d2)
    road = layout.drivable_union()
    assert road.geom_type == "Polygon"
    # Drivable area: the two roads (parking strips included) plus curb fillets, nothing else.
    expected = 4 * (arm - INTER_HALF) * 2 * DRIVABLE_HALF + (2 * INTER_HALF) ** 2 - 4 * (
        (INTER_HALF - DRIVABLE_HALF) ** 2 * np.pi / 4)
    assert road.area == pytest.approx(expected, rel=2e-3)
    for ln in layout.lanes:
        for xy in (ln.left, ln.right):
            assert road.buffer(1e-6).contains(LineString(xy))


def test_world_deterministic_and_seed_dependent():
    clear_world_cache()
    a = build_world(11, SMALL)
    clear_world_cache()
    b = build_world(11, SMALL)
    assert a is not b and a.log_id == b.log_id
    np.testing.assert_array_equal(a.buildings.center, b.buildings.center)
    assert a.actors == b.actors
    np.testing.assert_array_equal(a.timeline.sweeps_ns, b.timeline.sweeps_ns)
    ts = int(a.timeline.sweeps_ns[-1])
    np.testing.assert_array_equal(a.city_T_ego_at(ts), b.city_T_ego_at(ts))
    c = build_world(12, SMALL)
    assert c.log_id != a.log_id
    assert [x.track_uuid for x in c.actors] != [x.track_uuid for x in a.actors]
    assert not np.array_equal(c.origin_city, a.origin_city)
    with pytest.raises(ValueError, match="seed"):
        build_world(-1, SMALL)


def test_ego_trajectory_and_city_offsets():
    world = build_world(4, SynthConfig(seconds=2.0))
    ts = world.timeline.all_sensor_ns()
    city_T_ego = world.city_T_ego_at(ts)
    assert np.all(np.abs(world.origin_city[:2]) > 1000.0)  # km-scale city coordinates
    assert world.ground_z_city != 0.0 and float(np.float16(world.ground_z_city)) == world.ground_z_city
    np.testing.assert_allclose(city_T_ego[:, 2, 3], world.ground_z_city + EGO_ORIGIN_HEIGHT_M, atol=1e-9)
    np.testing.assert_allclose(city_T_ego[:, 2, :3], [[0, 0, 1]] * len(ts), atol=1e-12)  # level, yaw only
    t_s = world.seconds_since_start(ts)
    speed = np.linalg.norm(np.diff(city_T_ego[:, :2, 3], axis=0), axis=1) / np.diff(t_s)
    assert np.all((speed > 7.9) & (speed < 10.2))
    # Heading follows the velocity (no crabbing).
    vel = np.diff(city_T_ego[:, :2, 3], axis=0)
    mid_x_axis = city_T_ego[:-1, :2, 0] + city_T_ego[1:, :2, 0]
    heading = np.arctan2(mid_x_axis[:, 1], mid_x_axis[:, 0])
    np.testing.assert_allclose(np.arctan2(vel[:, 1], vel[:, 0]), heading, atol=2e-3)
    # city_T_local is a pure translation; local_T_city is its inverse.
    np.testing.assert_allclose(world.city_T_local @ world.local_T_city, np.eye(4), atol=1e-12)


def test_timeline_matches_av2_rates():
    tl = make_timeline(np.random.default_rng(0), 30, list(CAMERA_PHASE_NS))
    assert np.all(tl.sweeps_ns % 1000 == 0)  # lidar stamps are whole microseconds
    assert np.all(np.abs(np.diff(tl.sweeps_ns) - 100_000_000) <= 400_000)
    for ch, ts in tl.images_ns.items():
        assert len(ts) == 60 and np.all(np.diff(ts) > 0), ch
        nearest = np.abs(ts[:, None] - tl.sweeps_ns[None, :]).min(axis=0)
        assert nearest.max() < 25_000_000, ch  # av2's get_closest_img_fpath tolerance
    all_ns = tl.all_sensor_ns()
    assert np.all(np.diff(all_ns) > 0)


def test_texture_mip_levels_stay_centred_on_paint():
    """A solid line's brightness centroid must stay on the line at every mip level (pyrDown
    coordinate convention), else distant paint would render shifted."""
    layout = build_road_layout(arm_length_for(40.0))
    layer = draw_layer(layout, 10.0, -10.0, 40.0, 20.0, 0.05, salt=3)
    from nuav2.synth.texture import GroundTexture

    tex = GroundTexture((layer,))
    ys = np.linspace(-ROAD_HALF - 0.6, -ROAD_HALF + 0.6, 241)  # across the solid white edge at y = -7
    xy = np.column_stack([np.full_like(ys, 25.0), ys])
    for level in range(4):
        fp = np.full(len(ys), 0.05 * 2.0**level)
        lum = tex.sample_rgb(xy, fp).mean(axis=1)
        excess = lum - np.median(lum)
        weight = np.clip(excess - 0.3 * excess.max(), 0.0, None)  # the paint, above the asphalt grain
        centre = float(np.sum(weight * ys) / np.sum(weight))
        # Filtering is symmetric, so the centroid stays put; a half-texel convention slip at
        # level l would move it by (2**l - 1) * 0.025 m.
        assert abs(centre + ROAD_HALF) <= 0.03, (level, centre)
        assert excess.max() > 8
    refl = tex.sample_reflectivity(np.array([[25.0, -ROAD_HALF], [25.0, -5.25]]))
    assert refl[0] == MATERIALS[MAT["white_paint"]][3] and refl[1] == MATERIALS[MAT["asphalt"]][3]
    outside = tex.sample_rgb(np.array([[500.0, 500.0]]), np.array([0.05]))
    np.testing.assert_allclose(outside[0], MATERIALS[MAT["grass"]][1])


def test_load_world_errors_name_the_file(tmp_path):
    with pytest.raises(FileNotFoundError, match=WORLD_FILE):
        load_world(tmp_path)
    world = build_world(2, SMALL)
    rec = world.describe()
    (tmp_path / WORLD_FILE).write_text(json.dumps(rec))
    assert load_world(tmp_path) is world
    (tmp_path / WORLD_FILE).write_text(json.dumps({**rec, "log_id": "0" * 36}))
    with pytest.raises(ValueError, match=f"{WORLD_FILE}.*does not match"):
        load_world(tmp_path)
    (tmp_path / WORLD_FILE).write_text(json.dumps({**rec, "config": {**rec["config"], "seconds": -1}}))
    with pytest.raises(ValueError, match=f"{WORLD_FILE}.*seconds"):
        load_world(tmp_path)
    (tmp_path / WORLD_FILE).write_text("{not json")
    with pytest.raises(ValueError, match="not valid JSON"):
        load_world(tmp_path)
