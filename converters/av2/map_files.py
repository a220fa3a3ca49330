"""The map directory's non-vector parts: city name/frame from the archive filename, ground-height raster."""

from __future__ import annotations

import json
import logging
import re
from pathlib import Path

import numpy as np

from converters.av2.errors import AV2LogError
from nuav2.scene import GroundHeightRaster

log = logging.getLogger(__name__)

MAP_ARCHIVE_RE = re.compile(r"^log_map_archive_.+____(([A-Z]{3})_city_\d+)\.json$")


def _one(map_dir: Path, pattern: str, required: bool) -> Path | None:
    found = sorted(map_dir.glob(pattern))
    if len(found) > 1:
        names = [p.name for p in found]
        raise AV2LogError(map_dir, f"{len(found)} files match {pattern!r}, expected one: {names}")
    if not found and required:
        raise AV2LogError(map_dir, f"no file matches {pattern!r}")
    return found[0] if found else None


def city_from_map_dir(map_dir: Path) -> tuple[str, str]:
    """(city, city_frame), e.g. ("PIT", "PIT_city_57819") from log_map_archive_<id>____PIT_city_57819.json."""
    if not map_dir.is_dir():
        raise AV2LogError(map_dir, "map directory not found (the city name is read from its archive file)")
    path = _one(map_dir, "log_map_archive_*.json", required=True)
    assert path is not None
    m = MAP_ARCHIVE_RE.match(path.name)
    if not m:
        raise AV2LogError(path, "map archive name does not end in ____<CITY>_city_<n>.json")
    return m.group(2), m.group(1)


def read_ground_height(map_dir: Path) -> GroundHeightRaster | None:
    """The ground-height raster and its city->image Sim(2); None (logged) when the log ships none."""
    npy = _one(map_dir, "*_ground_height_surface____*.npy", required=False)
    sim2 = _one(map_dir, "*___img_Sim2_city.json", required=False)
    if npy is None or sim2 is None:
        log.info("%s: no ground-height raster and Sim(2) pair; ground height unavailable", map_dir)
        return None
    try:
        heights = np.load(npy, allow_pickle=False)
    except (OSError, ValueError) as e:
        raise AV2LogError(npy, f"unreadable .npy ({e})") from e
    if heights.ndim != 2 or heights.dtype.kind != "f":
        raise AV2LogError(npy, f"expected a 2-D float array, got {heights.dtype} {heights.shape}")
    if np.isinf(heights).any():
        raise AV2LogError(npy, "ground heights contain Inf")
    try:
        d = json.loads(sim2.read_text())
        R = np.asarray(d["R"], dtype=np.float64).reshape(2, 2)
        t = np.asarray(d["t"], dtype=np.float64).reshape(2)
        s = float(d["s"])
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise AV2LogError(sim2, f"expected JSON with R (4 numbers), t (2), s "
                                f"({type(e).__name__}: {e})") from e
    if not (np.isfinite(R).all() and np.isfinite(t).all() and np.isfinite(s) and s > 0):
        raise AV2LogError(sim2, f"Sim(2) must be finite with s > 0, got R={R.tolist()} t={t.tolist()} s={s}")
    return GroundHeightRaster(heights=heights.astype(np.float32), R=R, t=t, s=s)
