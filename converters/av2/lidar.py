"""LiDAR sweeps of an AV2 log: the file list (``sensors/lidar/<ts_ns>.feather``) and the lazy loader."""

from __future__ import annotations

import logging
import re
from pathlib import Path

import numpy as np

from converters.av2.errors import AV2LogError, require_file
from converters.av2.feather import INTEGER, NUMBER, read_columns
from nuav2.scene import LidarPoints, LidarSweepRef

log = logging.getLogger(__name__)

LIDAR_DIR = Path("sensors") / "lidar"
SWEEP_NAME_RE = re.compile(r"^(\d+)\.feather$")
SWEEP_COLUMNS = {"x": NUMBER, "y": NUMBER, "z": NUMBER, "intensity": NUMBER, "laser_number": INTEGER}


def list_sweeps(log_dir: Path) -> list[LidarSweepRef]:
    """Sweeps sorted by timestamp; the file name is the sweep time in ns."""
    lidar_dir = log_dir / LIDAR_DIR
    if not lidar_dir.is_dir():
        raise AV2LogError(lidar_dir, "lidar directory not found")
    sweeps, stray = [], []
    for p in lidar_dir.iterdir():
        m = SWEEP_NAME_RE.match(p.name)
        if m:
            require_file(p)  # named right but unreadable (dangling link, directory): fails the log
            sweeps.append(LidarSweepRef(int(m.group(1)), p))
        else:
            stray.append(p.name)
    if stray:
        log.warning("%s: ignored %d entries not named <timestamp_ns>.feather, e.g. %s", lidar_dir, len(stray),
                    sorted(stray)[:3])
    if not sweeps:
        raise AV2LogError(lidar_dir, "no <timestamp_ns>.feather sweeps")
    sweeps.sort(key=lambda s: s.timestamp_ns)
    for a, b in zip(sweeps, sweeps[1:]):
        if a.timestamp_ns == b.timestamp_ns:
            raise AV2LogError(lidar_dir, f"files {a.path.name} and {b.path.name} name the same timestamp")
    return sweeps


def load_av2_sweep(ref: LidarSweepRef) -> LidarPoints:
    """One sweep in the ego frame: float16 xyz widened to float64; non-finite points dropped (logged)."""
    cols = read_columns(ref.path, SWEEP_COLUMNS)
    xyz_ego = np.column_stack([cols["x"], cols["y"], cols["z"]]).astype(np.float64)
    intensity = np.asarray(cols["intensity"]).astype(np.float32)
    laser = np.asarray(cols["laser_number"])
    if laser.size and (laser.min() < 0 or laser.max() > 255):
        raise AV2LogError(ref.path, f"laser_number outside 0..255 ({laser.min()}..{laser.max()})")
    laser = laser.astype(np.uint8)
    ok = np.isfinite(xyz_ego).all(axis=1) & np.isfinite(intensity)
    if not ok.all():
        log.warning("%s: dropped %d points with non-finite values", ref.path, int((~ok).sum()))
        xyz_ego, intensity, laser = xyz_ego[ok], intensity[ok], laser[ok]
    return LidarPoints(xyz_ego=xyz_ego, intensity=intensity, laser_number=laser)
