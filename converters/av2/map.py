"""An AV2 log's vector map (``map/log_map_archive_*.json``) as a ``nuav2.scene.VectorMap``.

Read through av2's own ``ArgoverseStaticMap.from_map_dir`` (vector layers only, no rasters) so
AV2's parsing rules apply; the city code comes from the archive's file name, which is the
only place AV2 records it. Coordinates stay in the city frame, float64.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from av2.map.map_api import ArgoverseStaticMap

from converters.av2.errors import AV2LogError
from converters.av2.map_files import city_from_map_dir
from nuav2.scene import DrivableArea, LaneSegment, PedCrossing, VectorMap


def _xyz(arr, path: Path, what: str, min_points: int, max_points: int | None = None) -> np.ndarray:
    xyz = np.asarray(arr, dtype=np.float64)
    n_ok = xyz.ndim == 2 and min_points <= len(xyz) <= (max_points or len(xyz))
    if not n_ok or xyz.shape[1] != 3:
        want = f"{min_points}" if max_points == min_points else f"at least {min_points}"
        raise AV2LogError(path, f"{what}: expected {want} x/y/z points, got shape {xyz.shape}")
    if not np.all(np.isfinite(xyz)):
        raise AV2LogError(path, f"{what}: coordinates contain NaN/Inf")
    return xyz


def _value(enum_or_str) -> str:
    return str(getattr(enum_or_str, "value", enum_or_str))


def vector_map_from_dir(map_dir: Path) -> VectorMap:
    """The vector map of one AV2 log; raises ``AV2LogError`` naming the file on malformed input."""
    map_dir = Path(map_dir)
    city, _city_frame = city_from_map_dir(map_dir)
    archive = sorted(map_dir.glob("log_map_archive_*.json"))[0]
    try:
        static_map = ArgoverseStaticMap.from_map_dir(map_dir, build_raster=False)
    except (json.JSONDecodeError, KeyError, TypeError, ValueError, IndexError, AttributeError) as e:
        raise AV2LogError(archive, f"malformed vector map ({type(e).__name__}: {e})") from e

    lanes: dict[int, LaneSegment] = {}
    for lane_id, ls in static_map.vector_lane_segments.items():
        what = f"lane segment {lane_id}"
        lanes[int(lane_id)] = LaneSegment(
            id=int(lane_id),
            left_boundary=_xyz(ls.left_lane_boundary.xyz, archive, f"{what} left boundary", 1),
            right_boundary=_xyz(ls.right_lane_boundary.xyz, archive, f"{what} right boundary", 1),
            left_mark_type=_value(ls.left_mark_type),
            right_mark_type=_value(ls.right_mark_type),
            is_intersection=bool(ls.is_intersection),
            lane_type=_value(ls.lane_type),
            successors=tuple(int(s) for s in ls.successors),
            predecessors=tuple(int(p) for p in ls.predecessors),
            left_neighbor_id=None if ls.left_neighbor_id is None else int(ls.left_neighbor_id),
            right_neighbor_id=None if ls.right_neighbor_id is None else int(ls.right_neighbor_id),
        )
    crossings = {
        int(cid): PedCrossing(int(cid), _xyz(pc.edge1.xyz, archive, f"crossing {cid} edge1", 2, 2),
                              _xyz(pc.edge2.xyz, archive, f"crossing {cid} edge2", 2, 2))
        for cid, pc in static_map.vector_pedestrian_crossings.items()
    }
    areas = {
        int(aid): DrivableArea(int(aid), _xyz(da.xyz, archive, f"drivable area {aid}", 1))
        for aid, da in static_map.vector_drivable_areas.items()
    }
    return VectorMap(city_name=city, lane_segments=lanes, ped_crossings=crossings, drivable_areas=areas)
