"""The AV2 map files of a synthetic log: vector map JSON, ground-height raster, its Sim(2).

Formats follow av2-api 0.3.6 (``map/map_api.py``): dicts keyed by string ids with int ``id``
fields, city-frame points quantised to 1 cm, unclosed drivable-area rings; the ground height
is float16 at 0.30 m/px with NaN outside the region of interest (drivable area + 5 m), and
``value = array[int(p.y), int(p.x)]`` with ``p = s * (R xy + t)``.
"""

from __future__ import annotations

import io
import json
from pathlib import Path

import cv2
import numpy as np
from shapely.geometry import Polygon

from nuav2.atomic import atomic_write_bytes
from nuav2.synth.world import SyntheticWorld

GROUND_RES_M = 0.3
GROUND_ROI_MARGIN_M = 5.0
_SHIFT = 4


def _points(xy_local: np.ndarray, world: SyntheticWorld) -> list[dict]:
    """City-frame points on the road surface (the relief; the kerb step is off the road)."""
    xy_local = np.asarray(xy_local, np.float64)[:, :2]
    xy = xy_local + world.origin_city[:2]
    if world.terrain.flat:
        z = round(world.ground_z_city, 2)
        return [{"x": round(float(x), 2), "y": round(float(y), 2), "z": z} for x, y in xy]
    zs = world.ground_z_city + world.terrain.relief(xy_local)
    return [{"x": round(float(x), 2), "y": round(float(y), 2), "z": round(float(z), 2)}
            for (x, y), z in zip(xy, zs)]


def vector_map_dict(world: SyntheticWorld) -> dict:
    """The ``log_map_archive_*.json`` content (city frame)."""
    layout = world.map_layout
    lanes = {}
    for ln in layout.lanes:
        lanes[str(ln.id)] = {
            "id": ln.id, "is_intersection": ln.is_intersection, "lane_type": "VEHICLE",
            "left_lane_boundary": _points(ln.left, world), "left_lane_mark_type": ln.left_mark,
            "right_lane_boundary": _points(ln.right, world), "right_lane_mark_type": ln.right_mark,
            "successors": list(ln.successors), "predecessors": list(ln.predecessors),
            "right_neighbor_id": ln.right_neighbor_id, "left_neighbor_id": ln.left_neighbor_id,
        }
    crossings = {str(c.id): {"edge1": _points(c.edge1, world), "edge2": _points(c.edge2, world), "id": c.id}
                 for c in layout.crosswalks}
    areas = {str(i): {"area_boundary": _points(ring, world), "id": i} for i, ring in layout.drivable_areas}
    return {"pedestrian_crossings": crossings, "lane_segments": lanes, "drivable_areas": areas}


def ground_height_raster(world: SyntheticWorld) -> tuple[np.ndarray, dict]:
    """(float16 heights, Sim2 dict) over the map's drivable area plus a margin; NaN outside the ROI."""
    roi = world.map_layout.drivable_union().buffer(GROUND_ROI_MARGIN_M, quad_segs=8)
    x0, y0, x1, y1 = roi.bounds
    origin_xy = world.origin_city[:2]
    # Whole-decimetre raster origin in the city frame, so the Sim2 translation is exact in JSON.
    cx0 = float(np.floor((x0 + origin_xy[0]) * 10) / 10)
    cy0 = float(np.floor((y0 + origin_xy[1]) * 10) / 10)
    s = 1.0 / GROUND_RES_M
    w = int(np.ceil((x1 + origin_xy[0] - cx0) * s)) + 1
    h = int(np.ceil((y1 + origin_xy[1] - cy0) * s)) + 1
    mask = np.zeros((h, w), np.uint8)
    polys = [roi] if isinstance(roi, Polygon) else list(roi.geoms)
    for poly in polys:
        # Cell coordinates: cell i covers [i, i + 1), so its centre sits at i + 0.5.
        ring = (np.asarray(poly.exterior.coords) + origin_xy - (cx0, cy0)) * s
        cv2.fillPoly(mask, [np.round((ring - 0.5) * (1 << _SHIFT)).astype(np.int32)], 1, cv2.LINE_8, _SHIFT)
    if world.terrain.flat:
        z = np.float16(world.ground_z_city)
    else:  # the surface at each cell centre, kerbs and sidewalks included, as AV2's raster has them
        jj, ii = np.meshgrid(np.arange(w), np.arange(h))
        centres = np.column_stack([(jj.ravel() + 0.5) / s + cx0, (ii.ravel() + 0.5) / s + cy0]) - origin_xy
        z = (world.ground_z_city + world.terrain.height(centres)).reshape(h, w)
    heights = np.where(mask.astype(bool), z, np.float16(np.nan)).astype(np.float16)
    sim2 = {"R": [1.0, 0.0, 0.0, 1.0], "t": [-cx0, -cy0], "s": s}
    return heights, sim2


def map_file_names(world: SyntheticWorld) -> tuple[str, str, str]:
    """(vector map, ground height, Sim2) file names as av2's globs expect them."""
    number = world.city_frame.rsplit("_", 1)[-1]
    return (f"log_map_archive_{world.log_id}____{world.city}_city_{number}.json",
            f"{world.log_id}_ground_height_surface____{world.city}.npy",
            f"{world.log_id}___img_Sim2_city.json")


def write_map_dir(world: SyntheticWorld, map_dir: Path) -> list[Path]:
    """Write the three map files (each atomically) into ``map_dir``; returns their paths."""
    vec_name, gh_name, sim_name = map_file_names(world)
    heights, sim2 = ground_height_raster(world)
    buf = io.BytesIO()
    np.save(buf, heights, allow_pickle=False)
    paths = [map_dir / vec_name, map_dir / gh_name, map_dir / sim_name]
    atomic_write_bytes(paths[0], json.dumps(vector_map_dict(world)).encode())
    atomic_write_bytes(paths[1], buf.getvalue())
    atomic_write_bytes(paths[2], json.dumps(sim2).encode())
    return paths
