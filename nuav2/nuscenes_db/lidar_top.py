"""The virtual LIDAR_TOP: a source sweep re-expressed in the output rig's LIDAR_TOP frame.

nuScenes code (and MapTR) reads ``*.pcd.bin`` as float32 rows of (x, y, z, intensity, ring)
in the LIDAR_TOP sensor frame. AV2 stores one merged, motion-compensated sweep per timestamp
in its own ego frame, so the sweep is moved ``egoS -> egoT -> LIDAR_TOP`` in float64 and cast
to float32 only at the end (the cast rounds each coordinate to half a float32 ulp: <= 1 µm
within 16 m, <= 8 µm at 200 m).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from nuav2.atomic import atomic_write_bytes
from nuav2.geometry import F64, T_inverse, transform_points
from nuav2.scene import LidarPoints

PCD_COLUMNS = 5  # x, y, z, intensity, ring index


def lidar_T_egoS(egoT_T_lidar: F64, egoS_T_egoT: F64) -> F64:
    """Transform from the source ego frame into the output LIDAR_TOP frame."""
    return T_inverse(egoT_T_lidar) @ T_inverse(egoS_T_egoT)


def sweep_to_pcd_rows(points: LidarPoints, lidar_T_ego: F64) -> np.ndarray:
    """(N, 5) float32 rows in the LIDAR_TOP frame; points with a non-finite coordinate are dropped."""
    xyz = np.asarray(points.xyz_ego, dtype=np.float64).reshape(-1, 3)
    n = len(xyz)
    if len(points.intensity) != n or len(points.laser_number) != n:
        raise ValueError(f"sweep has {n} points but {len(points.intensity)} intensities and "
                         f"{len(points.laser_number)} ring indices")
    intensity = np.asarray(points.intensity, dtype=np.float64)
    ring = np.asarray(points.laser_number, dtype=np.float64)
    ok = np.all(np.isfinite(xyz), axis=1) & np.isfinite(intensity) & np.isfinite(ring)
    xyz_lidar = transform_points(lidar_T_ego, xyz[ok])
    rows = np.empty((int(ok.sum()), PCD_COLUMNS), dtype=np.float32)
    rows[:, :3] = xyz_lidar
    rows[:, 3] = intensity[ok]
    rows[:, 4] = ring[ok]
    if not np.all(np.isfinite(rows)):
        raise ValueError("LIDAR_TOP points overflow float32 (coordinates beyond 3.4e38 m?)")
    return rows


def write_pcd_bin(path: str | Path, rows: np.ndarray) -> None:
    """Atomically write (N, 5) float32 rows as nuScenes ``.pcd.bin``."""
    rows = np.ascontiguousarray(rows, dtype=np.float32)
    if rows.ndim != 2 or rows.shape[1] != PCD_COLUMNS:
        raise ValueError(f"pcd.bin rows must be (N, {PCD_COLUMNS}), got {rows.shape}")
    atomic_write_bytes(path, rows.tobytes())


def read_pcd_bin(path: str | Path) -> np.ndarray:
    """(N, 5) float32 rows of a ``.pcd.bin`` file; a size that is not a whole number of rows is an error."""
    data = np.fromfile(path, dtype=np.float32)
    if data.size % PCD_COLUMNS:
        raise ValueError(f"{path}: {data.size} float32 values is not a multiple of {PCD_COLUMNS}")
    return data.reshape(-1, PCD_COLUMNS)
