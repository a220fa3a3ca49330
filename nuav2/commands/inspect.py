"""``nuav2 inspect LOG_DIR``: print what the AV2 reader finds in one log, as JSON."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from nuav2.cli_types import number, path

# Camera-to-sweep sync tolerance in ms: positive; AV2 sweeps come every 100 ms, so a second is
# far beyond any meaningful pairing (and keeps the value in nanoseconds an ordinary integer).
TOLERANCE_MS_MAX = 1000.0


def summarize_log(log_dir: Path, calibration_dir: Path | None, require_cameras: bool,
                  tolerance_ms: float) -> dict:
    """Counts and spans of one log's poses, sweeps, images, boxes, map and ground height."""
    from converters.av2 import read_log, synced_sweeps
    from nuav2.ground_height import estimate_origin_height

    tol_ns = int(round(tolerance_ms * 1e6))
    scene = read_log(log_dir, calibration_dir, require_cameras=require_cameras, camera_tolerance_ns=tol_ns)
    ts = scene.pose_timestamps_ns
    ann = scene.annotations
    out: dict = {
        "log_id": scene.log_id, "split": scene.split, "city": scene.city, "city_frame": scene.city_frame,
        "poses": {"n": int(len(ts)), "span_s": float((ts[-1] - ts[0]) / 1e9)},
        "lidar_sweeps": len(scene.lidar_sweeps),
        "cameras": {ch: len(f) for ch, f in scene.camera_frames.items()},
        "synced_sweeps": len(synced_sweeps(scene, tol_ns)) if any(scene.camera_frames.values()) else 0,
        "camera_tolerance_ms": tolerance_ms,
        "annotations": {"rows": len(ann), "tracks": int(len(set(ann.track_id))),
                        "timestamps": int(len(np.unique(ann.timestamp_ns))),
                        "categories": sorted(set(ann.category))},
        "rig": {"cameras": scene.rig.camera_channels, "lidars": [lid.channel for lid in scene.rig.lidars],
                "origin_height_m": scene.rig.origin_height_m},
    }
    vm = scene.vector_map
    out["vector_map"] = None if vm is None else {
        "lane_segments": len(vm.lane_segments), "ped_crossings": len(vm.ped_crossings),
        "drivable_areas": len(vm.drivable_areas)}
    if scene.ground_height is not None:
        est = estimate_origin_height(scene)
        out["ground_height"] = {"raster_shape": list(scene.ground_height.heights.shape),
                                "origin_height_m": {"mean": est.mean_m, "std": est.std_m, "min": est.min_m,
                                                    "max": est.max_m, "n": est.n}}
    return out


def _refuse_split_folder(log_dir: Path) -> None:
    """A split folder (``.../train``) given for a log: say so, instead of the reader's complaint about
    its missing calibration."""
    from converters.av2 import AV2LogError, find_logs
    from converters.av2.logs import maybe_log_dir
    from nuav2.cli import UsageError

    if not log_dir.is_dir() or maybe_log_dir(log_dir):
        return
    try:
        logs = [p.name for p in find_logs(log_dir)]
    except AV2LogError:
        return  # no logs in it either: the reader's own message names what is missing
    more = f", ... ({len(logs)} in all)" if len(logs) > 3 else ""
    raise UsageError(f"{log_dir}: not an AV2 log folder; it holds log folders "
                     f"({', '.join(logs[:3])}{more}): give one of them")


def _run(args: argparse.Namespace) -> int:
    _refuse_split_folder(args.log_dir)
    summary = summarize_log(args.log_dir, args.calibration_dir, not args.allow_missing_cameras,
                            args.tolerance_ms)
    print(json.dumps(summary, indent=1))
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("inspect", help="summarise what the AV2 reader finds in one log (JSON)")
    p.add_argument("log_dir", type=path, help="an AV2 sensor log directory")
    p.add_argument("--calibration", "--calibration-dir", dest="calibration_dir", type=path, default=None,
                   help="calibration to use instead of LOG_DIR/calibration (for fragments without one)")
    p.add_argument("--allow-missing-cameras", action="store_true",
                   help="read a log whose camera images are missing instead of failing")
    p.add_argument("--tolerance-ms", type=number(float, lo=0, hi=TOLERANCE_MS_MAX, lo_open=True),
                   default=25.0,
                   help="max |image - sweep| time for a sweep to count as synced, in (0, "
                        f"{TOLERANCE_MS_MAX:g}] ms (default 25)")
    p.set_defaults(func=_run)
