"""Where a converted log lives in nuScenes' "global" frame, and under which map location.

Design: one map location per log (``av2-<city>-<log id prefix>``). The nuScenes global
frame of that log is the AV2 city frame minus one rigid per-log offset, ``city_offset``
(x, y, z): x and y are whole metres chosen so every map and pose coordinate is >= ``MARGIN_M``
(the devkit's mask PNG puts (0, 0) at its bottom-left corner); z is the ground height under
the ego at the log's first pose, so ego poses sit near z = 0 as in nuScenes and the devkit,
which draws the 2-D map at z = 0 (``render_map_in_image``), draws it on the road. The frame is
a pure translation of the city frame, so sweeps aggregate exactly. Because each location covers
only its own log's map (~100 m around the trajectory), each semantic-prior PNG stays a few
thousand pixels wide however many logs a city split has. True city coordinates are
``global + city_offset``, written to ``<version>/nuav2_logs.json`` and to the expansion JSON's
``nuav2`` block.
"""

from __future__ import annotations

import hashlib
import re
from dataclasses import dataclass

import numpy as np

from nuav2.geometry import F64, translation_T

# The devkit's ego-centric underlay (render_sample_data(..., underlay_map=True), axes_limit 40 m by default)
# crops sqrt(2) x axes_limit around the ego without clipping: an empty crop past the canvas edge. 80 m
# serves axes limits up to 56 m.
MARGIN_M = 80.0
LOCATION_RE = re.compile(r"^av2-[a-z]{3}-[0-9a-f]{8}$")
OFFSET_KEY = "city_offset"  # field name in nuav2_logs.json, shard meta and the expansion's nuav2 block


@dataclass(frozen=True)
class MapFrame:
    location: str
    city_offset: F64  # (3,) float64: city = global + city_offset (x, y whole metres; z the ground)

    def __post_init__(self) -> None:
        off = np.asarray(self.city_offset, dtype=np.float64).reshape(-1)
        if off.shape != (3,) or not np.all(np.isfinite(off)):
            raise ValueError(f"location {self.location}: city_offset must be 3 finite numbers, got {off}")
        object.__setattr__(self, "city_offset", off)

    @property
    def global_T_city(self) -> F64:
        return translation_T(*(-self.city_offset))

    @property
    def city_T_global(self) -> F64:
        return translation_T(*self.city_offset)

    def city_to_global_xy(self, xy_city: np.ndarray) -> F64:
        return np.asarray(xy_city, dtype=np.float64)[..., :2] - self.city_offset[:2]

    def global_to_city_xy(self, xy_global: np.ndarray) -> F64:
        return np.asarray(xy_global, dtype=np.float64)[..., :2] + self.city_offset[:2]


def location_id(log_id: str) -> str:
    """The log's part of its map location: an AV2 log id's first 8 hex digits (unique over AV2's
    logs), else 8 hex digits of the id's hash (``run1`` and ``run2`` must not share a map)."""
    head = log_id.lower()[:8]
    return head if re.fullmatch(r"[0-9a-f]{8}", head) else hashlib.md5(log_id.encode()).hexdigest()[:8]


def location_for(city: str, log_id: str) -> str:
    """Map location name of a log, e.g. ``av2-pit-adcf7d18``."""
    return f"av2-{city.lower()[:3]}-{location_id(log_id)}"


def map_frame_for(city: str, log_id: str, city_xy_points: np.ndarray, ground_z_city: float = 0.0) -> MapFrame:
    """Frame whose offset puts every given city point (map vertices and poses) >= MARGIN_M in x and y
    and the ground height ``ground_z_city`` (under the first pose) at global z = 0."""
    pts = np.asarray(city_xy_points, dtype=np.float64).reshape(-1, 2)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if len(pts) == 0:
        raise ValueError(f"log {log_id}: no finite map or pose coordinates to place the map frame")
    if not np.isfinite(ground_z_city):
        raise ValueError(f"log {log_id}: ground height {ground_z_city} is not finite")
    offset_xy = np.floor(pts.min(axis=0) - MARGIN_M)
    return MapFrame(location_for(city, log_id), np.array([*offset_xy, float(ground_z_city)]))


def city_offset_of(record: dict, where: str) -> F64:
    """The (3,) city offset stored in a ``nuav2_logs.json`` / shard meta / expansion ``nuav2`` record."""
    try:
        off = np.asarray(record[OFFSET_KEY], dtype=np.float64).reshape(-1)
    except (KeyError, TypeError, ValueError) as e:
        raise ValueError(f"{where}: no readable '{OFFSET_KEY}' [x, y, z] ({type(e).__name__}: {e}); "
                         "converted by an older nuav2? convert again") from None
    if off.shape != (3,) or not np.all(np.isfinite(off)):
        raise ValueError(f"{where}: '{OFFSET_KEY}' must be 3 finite numbers [x, y, z], "
                         f"got {record[OFFSET_KEY]}")
    return off
