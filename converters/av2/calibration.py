"""The source rig of one AV2 log, built from its own calibration files.

Extrinsics and intrinsics vary per log (mm, tenths of a degree), so each log gets its own
``Rig``. What the calibration does not hold comes from the built-in ``av2`` rig spec: the ego
origin height above ground, the ego-body mask polygons and the virtual ``LIDAR_TOP`` (nuScenes
extrinsic, so MapTR patches line up).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from converters.av2.errors import AV2LogError
from converters.av2.feather import INTEGER, NUMBER, TEXT, read_columns, require_finite
from nuav2.geometry import T_to_quat_trans
from nuav2.rig import CameraSpec, Rig, RigSpecError, load_rig, rig_from_dict

log = logging.getLogger(__name__)

EXTRINSICS_FILE = "egovehicle_SE3_sensor.feather"
INTRINSICS_FILE = "intrinsics.feather"
POSE_COLUMNS = ("qw", "qx", "qy", "qz", "tx_m", "ty_m", "tz_m")
# Image sizes are integers (uint16 in AV2): a float size would be truncated silently.
INTRINSIC_COLUMNS = {"fx_px": NUMBER, "fy_px": NUMBER, "cx_px": NUMBER, "cy_px": NUMBER,
                     "height_px": INTEGER, "width_px": INTEGER}
# Calibration quaternions are stored as float64 from a unit quaternion; anything further off is corrupt.
QUAT_NORM_TOL = 1e-3


def _scaled_polygons(template: CameraSpec, width: int, height: int) -> list[list[list[float]]]:
    """The template camera's mask polygons at this resolution (pixel-centre convention)."""
    sx, sy = width / template.width, height / template.height
    return [np.column_stack([(p[:, 0] + 0.5) * sx - 0.5, (p[:, 1] + 0.5) * sy - 0.5]).tolist()
            for p in template.ego_mask_polygons]


def _pose_fields(path: Path, row: int, name: str, cols: dict[str, np.ndarray]) -> dict:
    q = np.array([cols[k][row] for k in ("qw", "qx", "qy", "qz")], dtype=np.float64)
    norm = float(np.linalg.norm(q))
    if abs(norm - 1.0) > QUAT_NORM_TOL:
        raise AV2LogError(path, f"sensor '{name}' (row {row}) has a non-unit quaternion (norm {norm:.6g})")
    t = [float(cols[k][row]) for k in ("tx_m", "ty_m", "tz_m")]
    return {"translation": t, "rotation": (q / norm).tolist()}


def rig_from_calibration(calibration_dir: Path, channels: list[str] | None = None) -> Rig:
    """Rig of a log from ``calibration_dir`` (holding egovehicle_SE3_sensor + intrinsics feathers).

    ``channels`` restricts the cameras (default: every camera with both extrinsics and intrinsics).
    """
    ext_path = calibration_dir / EXTRINSICS_FILE
    int_path = calibration_dir / INTRINSICS_FILE
    ext = read_columns(ext_path, {"sensor_name": TEXT, **dict.fromkeys(POSE_COLUMNS, NUMBER)})
    require_finite(ext_path, ext, POSE_COLUMNS)
    intr = read_columns(int_path, {"sensor_name": TEXT, **INTRINSIC_COLUMNS})
    require_finite(int_path, intr, INTRINSIC_COLUMNS)
    template = load_rig("av2")
    template_cams = {c.channel: c for c in template.cameras}
    ext_rows = {str(n): i for i, n in enumerate(ext["sensor_name"])}
    int_rows = {str(n): i for i, n in enumerate(intr["sensor_name"])}
    for path, names in ((ext_path, ext["sensor_name"]), (int_path, intr["sensor_name"])):
        if len(set(names)) != len(names):
            raise AV2LogError(path, f"repeated sensor_name in {sorted(map(str, names))}")

    # Order cameras like the built-in rig (front first), unknown extras after, by name.
    known_order = [c for c in template_cams if c in int_rows]
    wanted = known_order + sorted(set(int_rows) - set(known_order))
    if channels is not None:
        absent = [c for c in channels if c not in int_rows]
        if absent:
            raise AV2LogError(int_path,
                              f"no intrinsics for requested camera(s) {absent}; has {sorted(int_rows)}")
        wanted = [c for c in wanted if c in channels]
    cameras = []
    for name in wanted:
        if name not in ext_rows:
            raise AV2LogError(ext_path,
                              f"camera '{name}' has intrinsics in {int_path.name} but no extrinsics")
        i = int_rows[name]
        width, height = int(intr["width_px"][i]), int(intr["height_px"][i])
        cam = {"channel": name, "width": width, "height": height,
               "fx": float(intr["fx_px"][i]), "fy": float(intr["fy_px"][i]),
               "cx": float(intr["cx_px"][i]), "cy": float(intr["cy_px"][i]),
               **_pose_fields(ext_path, ext_rows[name], name, ext)}
        if name in template_cams:
            cam["ego_mask_polygons"] = _scaled_polygons(template_cams[name], width, height)
        cameras.append(cam)
    if not cameras:
        raise AV2LogError(int_path, "no camera has intrinsics")
    missing_intr = sorted(n for n in ext_rows if n not in int_rows and "lidar" not in n)
    if missing_intr and channels is None:
        log.warning("%s: camera(s) %s have extrinsics but no intrinsics; left out of the rig", int_path,
                    missing_intr)

    lidars = [{"channel": n, **_pose_fields(ext_path, i, n, ext)}
              for n, i in ext_rows.items() if "lidar" in n]
    virtual = template.lidar(template.keyframe_lidar)
    q, t = T_to_quat_trans(virtual.ego_T_lidar)
    lidars.append({"channel": virtual.channel, "translation": t.tolist(), "rotation": q.tolist()})
    spec = {"name": "av2", "origin_height_m": template.origin_height_m,
            "keyframe_lidar": template.keyframe_lidar,
            "description": f"AV2 rig from {calibration_dir}; origin height, ego masks and virtual "
                           f"{virtual.channel} from {template.source_path}",
            "cameras": cameras, "lidars": lidars}
    try:
        return rig_from_dict(spec, src=str(calibration_dir))
    except RigSpecError as e:
        raise AV2LogError(calibration_dir, f"calibration does not make a valid rig ({e})") from e
