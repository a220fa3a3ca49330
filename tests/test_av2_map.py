"""converters.av2.map: the real AV2 vector map read through av2's API into nuav2's VectorMap."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from converters.av2.errors import AV2LogError
from converters.av2.map import vector_map_from_dir


@pytest.fixture(scope="module")
def fixture_map_dir(av2_fixture_log: Path) -> Path:
    return av2_fixture_log / "map"


def test_reads_fixture_map_like_av2(fixture_map_dir: Path):
    from av2.map.map_api import ArgoverseStaticMap

    vm = vector_map_from_dir(fixture_map_dir)
    ref = ArgoverseStaticMap.from_map_dir(fixture_map_dir, build_raster=False)
    assert vm.city_name == "PIT"
    assert (len(vm.lane_segments), len(vm.ped_crossings), len(vm.drivable_areas)) == (199, 11, 8)
    for lane_id, ls in ref.vector_lane_segments.items():
        ours = vm.lane_segments[lane_id]
        np.testing.assert_array_equal(ours.left_boundary, ls.left_lane_boundary.xyz)
        np.testing.assert_array_equal(ours.right_boundary, ls.right_lane_boundary.xyz)
        assert ours.successors == tuple(ls.successors) and ours.predecessors == tuple(ls.predecessors)
        assert ours.left_mark_type == ls.left_mark_type.value
        assert ours.right_mark_type == ls.right_mark_type.value
        assert ours.is_intersection == ls.is_intersection and ours.lane_type == ls.lane_type.value
        assert (ours.left_neighbor_id, ours.right_neighbor_id) == (ls.left_neighbor_id, ls.right_neighbor_id)
    for cid, pc in ref.vector_pedestrian_crossings.items():
        np.testing.assert_array_equal(vm.ped_crossings[cid].polygon, pc.polygon[:4])
    for aid, da in ref.vector_drivable_areas.items():
        np.testing.assert_array_equal(vm.drivable_areas[aid].boundary, da.xyz)
    lanes = vm.lane_segments.values()
    assert all(ln.left_boundary.dtype == np.float64 == ln.right_boundary.dtype for ln in lanes)


def _copy_map(src: Path, dst: Path) -> Path:
    dst.mkdir(parents=True)
    archive = next(src.glob("log_map_archive_*.json"))
    shutil.copy(archive, dst / archive.name)
    return dst / archive.name


def test_malformed_archives_name_the_file(fixture_map_dir: Path, tmp_path: Path):
    archive = _copy_map(fixture_map_dir, tmp_path / "broken" / "map")
    archive.write_text("{not json")
    with pytest.raises(AV2LogError, match=archive.name):
        vector_map_from_dir(archive.parent)

    archive = _copy_map(fixture_map_dir, tmp_path / "nan" / "map")
    data = json.loads(archive.read_text())
    lane = next(iter(data["lane_segments"].values()))
    lane["left_lane_boundary"][0]["x"] = float("nan")
    archive.write_text(json.dumps(data))
    with pytest.raises(AV2LogError, match=f"lane segment {lane['id']} left boundary: .* NaN"):
        vector_map_from_dir(archive.parent)

    archive = _copy_map(fixture_map_dir, tmp_path / "edge" / "map")
    data = json.loads(archive.read_text())
    pc = next(iter(data["pedestrian_crossings"].values()))
    pc["edge1"].append(pc["edge1"][0])
    archive.write_text(json.dumps(data))
    with pytest.raises(AV2LogError, match=f"crossing {pc['id']} edge1: expected 2 x/y/z points"):
        vector_map_from_dir(archive.parent)

    archive = _copy_map(fixture_map_dir, tmp_path / "missing_key" / "map")
    data = json.loads(archive.read_text())
    del next(iter(data["lane_segments"].values()))["successors"]
    archive.write_text(json.dumps(data))
    with pytest.raises(AV2LogError, match="malformed vector map"):
        vector_map_from_dir(archive.parent)


def test_missing_map_or_city_is_refused(fixture_map_dir: Path, tmp_path: Path):
    with pytest.raises(AV2LogError, match="map directory not found"):
        vector_map_from_dir(tmp_path / "nowhere")
    archive = _copy_map(fixture_map_dir, tmp_path / "nocity" / "map")
    archive.rename(archive.with_name("log_map_archive_abc.json"))
    with pytest.raises(AV2LogError, match="CITY"):
        vector_map_from_dir(archive.parent)
