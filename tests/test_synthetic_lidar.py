"""Synthetic lidar: points lie on the world's surfaces, in the ego frame, with AV2's beam layout."""

from __future__ import annotations

import numpy as np
import pytest

from nuav2.geometry import transform_points
from nuav2.synth import SynthConfig, build_world, cast_sweep
from nuav2.synth.road import ROAD_HALF
from nuav2.synth.world import EGO_ORIGIN_HEIGHT_M


@pytest.fixture(scope="module")
def sweep():
    world = build_world(8, SynthConfig(seconds=1.0))
    ts = int(world.timeline.sweeps_ns[4])
    return world, ts, cast_sweep(world, ts)


def test_sweep_size_beams_and_offsets(sweep):
    world, _, ret = sweep
    assert 15_000 < len(ret.offset_ns) < 40_000
    assert ret.laser_number.dtype == np.uint8 and ret.intensity.dtype == np.uint8
    assert set(np.unique(ret.laser_number)) <= set(range(64))
    assert (ret.laser_number < 32).sum() > 5000 and (ret.laser_number >= 32).sum() > 5000
    assert ret.offset_ns.dtype == np.int32 and np.all(np.diff(ret.offset_ns) >= 0)
    assert ret.offset_ns[0] >= 0 and ret.offset_ns[-1] < 100_000_000
    rng = np.linalg.norm(ret.xyz_ego, axis=1)
    assert rng.max() <= world.config.lidar_max_range_m + 2.0 and np.all(np.isfinite(ret.xyz_ego))


def test_ground_points_sit_at_minus_origin_height(sweep):
    _, _, ret = sweep
    ground = ret.box < 0
    assert ground.sum() > 3000
    z16 = ret.xyz_ego[ground, 2].astype(np.float16).astype(np.float64)
    step = float(np.spacing(np.float16(EGO_ORIGIN_HEIGHT_M)))
    assert np.all(np.abs(z16 + EGO_ORIGIN_HEIGHT_M) <= step)


def test_box_points_lie_on_box_surfaces_and_never_inside(sweep):
    world, ts, ret = sweep
    boxes = world.boxes_at(ts)
    local = transform_points(world.local_T_ego_at(ts), ret.xyz_ego)
    hit = ret.box >= 0
    assert hit.sum() > 1000
    R = boxes.rotations[ret.box[hit]]
    p_b = np.einsum("mji,mj->mi", R, local[hit] - boxes.center[ret.box[hit]])
    rel = np.abs(p_b) / (boxes.size[ret.box[hit]] / 2)
    np.testing.assert_allclose(rel.max(axis=1), 1.0, atol=1e-6)  # on the surface
    assert np.all(rel <= 1.0 + 1e-6)
    # No point (ground or box) strictly inside any box, even after float16 storage.
    xyz16 = transform_points(world.local_T_ego_at(ts), ret.xyz_ego.astype(np.float16).astype(np.float64))
    for i in range(len(boxes)):
        q = (xyz16 - boxes.center[i]) @ boxes.rotations[i]
        inside = np.all(np.abs(q) < boxes.size[i] / 2 - 0.05, axis=1)
        assert not inside.any(), i


def test_paint_is_brighter_than_asphalt(sweep):
    world, ts, ret = sweep
    local = transform_points(world.local_T_ego_at(ts), ret.xyz_ego)
    ground = ret.box < 0
    on_arm = np.abs(local[:, 0]) > 15.0
    edge_line = ground & on_arm & (np.abs(np.abs(local[:, 1]) - ROAD_HALF) < 0.04)
    lane = ground & on_arm & (np.abs(np.abs(local[:, 1]) - 5.25) < 1.0)
    assert edge_line.sum() >= 5 and lane.sum() >= 50
    assert ret.intensity[edge_line].mean() > 3 * ret.intensity[lane].mean()
