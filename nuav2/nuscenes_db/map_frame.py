"""Where a converted log lives in nuScenes' "global" frame, and under which map location.

Design: one map location per log (``av2-<city>-<log id prefix>``). The nuScenes global
frame of that log is the AV2 city frame shifted by a whole-metre ``city_xy_offset`` so all
map and pose coordinates are >= ``MARGIN_M`` (the devkit's mask PNG puts (0, 0) at its
bottom-left corner). z is kept as the city height. Because each location covers only its
own log's map (~100 m around the trajectory), each semantic-prior PNG stays a few thousand
pixels wide however many logs a city split has; the true city coordinates are
``global + city_xy_offset``, written to ``<version>/nuav2_logs.json`` and to the
expansion JSON's ``nuav2`` block.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from nuav2.geometry import F64, translation_T

MARGIN_M = 20.0
LOCATION_RE = re.compile(r"^av2-[a-z]{3}-[0-9a-f]{8}$")


@dataclass(frozen=True)
class MapFrame:
    location: str
    city_xy_offset: F64  # (2,) float64, whole metres

    @property
    def global_T_city(self) -> F64:
        return translation_T(-self.city_xy_offset[0], -self.city_xy_offset[1], 0.0)

    @property
    def city_T_global(self) -> F64:
        return translation_T(self.city_xy_offset[0], self.city_xy_offset[1], 0.0)

    def city_to_global_xy(self, xy_city: np.ndarray) -> F64:
        return np.asarray(xy_city, dtype=np.float64)[..., :2] - self.city_xy_offset

    def global_to_city_xy(self, xy_global: np.ndarray) -> F64:
        return np.asarray(xy_global, dtype=np.float64)[..., :2] + self.city_xy_offset


def location_for(city: str, log_id: str) -> str:
    """Map location name of a log, e.g. ``av2-pit-adcf7d18``."""
    hexid = re.sub(r"[^0-9a-f]", "", log_id.lower())[:8].ljust(8, "0")
    return f"av2-{city.lower()[:3]}-{hexid}"


def map_frame_for(city: str, log_id: str, city_xy_points: np.ndarray) -> MapFrame:
    """Frame whose offset puts every given city point (map vertices and poses) >= MARGIN_M."""
    pts = np.asarray(city_xy_points, dtype=np.float64).reshape(-1, 2)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if len(pts) == 0:
        raise ValueError(f"log {log_id}: no finite map or pose coordinates to place the map frame")
    offset = np.floor(pts.min(axis=0) - MARGIN_M)
    return MapFrame(location_for(city, log_id), offset)
