"""``nuav2 infos DATAROOT --version V --out DIR``: MapTRv2-compatible info .pkl files per split."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from nuav2.cli_types import non_negative_int, path, positive_float, positive_int


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "infos",
        help="export MapTRv2 info .pkl files (with vectorized map GT) for each split",
        description="Writes {prefix}_map_infos_temporal_{split}.pkl for the splits in VERSION/splits.json "
        "and the devkit's lists of VERSION's nuScenes release that hold scenes (or those given), in the "
        "layout MapTRv2's nuScenes dataset reads.",
    )
    p.add_argument("dataroot", type=path, help="nuScenes-format dataroot")
    p.add_argument("--version", help="table folder under DATAROOT (default: the only one there)")
    p.add_argument("--out", required=True, type=path, help="directory for the .pkl files")
    p.add_argument("--prefix", default="nuav2",
                   help="file name prefix (default: %(default)s; MapTR uses 'nuscenes')")
    p.add_argument("--splits", nargs="+", default=None,
                   help="split names (default: all in splits.json, and the devkit's lists of VERSION's "
                        "release with scenes present, e.g. mini_train mini_val on v1.0-mini)")
    p.add_argument("--max-sweeps", type=non_negative_int, default=10,
                   help="previous LIDAR_TOP sweeps per keyframe (>= 0; default 10)")
    p.add_argument(
        "--patch",
        type=positive_float,
        nargs=2,
        default=(60.0, 30.0),
        metavar=("FORWARD_M", "SIDE_M"),
        help="map patch size along lidar y (forward) and x (right) (default: 60 30)",
    )
    p.add_argument(
        "--path-root",
        default="",
        help="prefix written instead of DATAROOT in file paths, kept as given (e.g. ./data/nuav2 for MapTR)",
    )
    p.add_argument(
        "--cameras",
        nargs="+",
        default=None,
        metavar="CH",
        help="camera channels in this order (default: nuScenes' six in MapTR's order, else AV2's seven ring "
        "cameras in MapTR's AV2 order, else every camera sorted by name)",
    )
    p.add_argument("--workers", type=positive_int, default=1,
                   help="processes (or Ray actors) making the records, each holding the tables in memory; "
                        "with --executor ray, 1 means one actor per cluster CPU")
    p.add_argument("--executor", choices=["local", "ray"], default="local",
                   help="local processes (default) or Ray actors (needs nuav2[ray]; see docs/cluster.md)")
    p.add_argument("--ray-address", default=None, help="Ray cluster (default: RAY_ADDRESS, else a local one)")
    p.add_argument("--no-progress", action="store_true", help="no progress display")
    p.set_defaults(func=run)


def check_cameras(dataroot: Path, version: str, cameras: list[str] | None) -> None:
    """Refuse a ``--cameras`` channel twice or not a camera of the sensor table, before any work
    (a sample that lacks one is refused during the work, naming the sample)."""
    from nuav2.cli import UsageError
    from nuav2.cli_inputs import refuse_repeats
    from nuav2.maptr.infos import camera_sensor_channels

    if not cameras:
        return
    refuse_repeats("--cameras", cameras)
    try:
        sensors = json.loads((Path(dataroot) / version / "sensor.json").read_text())
        known = sorted(camera_sensor_channels(sensors))
    except (OSError, ValueError, TypeError, KeyError, AttributeError):
        return  # a damaged table is diagnosed (naming the file) when the work reads it
    missing = [c for c in cameras if c not in known]
    if missing:
        raise UsageError(f"--cameras: no camera channel {', '.join(missing)} in {dataroot}/{version}; "
                         f"its cameras: {', '.join(known) or 'none'}")


def check_infos_flags(args: argparse.Namespace) -> None:
    """--out must be a folder (or not exist yet); --prefix a plain file-name part, so every .pkl lands in
    --out (``../x`` wrote beside it, ``a/b`` into a subfolder); --ray-address needs --executor ray."""
    from nuav2.cli import UsageError

    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out {args.out}: is not a folder")
    if out.is_symlink() and not out.exists():
        raise UsageError(f"--out {args.out}: is a dangling symbolic link")
    prefix = args.prefix
    if not prefix or prefix in (".", "..") or "/" in prefix or "\\" in prefix or "\0" in prefix:
        raise UsageError(f"--prefix {prefix!r}: must be a file-name part (no '/', not '.' or '..')")
    if args.ray_address is not None and args.executor != "ray":
        raise UsageError("--ray-address applies to --executor ray only")


def run(args: argparse.Namespace) -> int:
    from nuav2.cli import UsageError, require_database
    from nuav2.cli_inputs import diagnosed_tables
    from nuav2.devkit_compat import HOOK_DIR
    from nuav2.executors.ray_tasks import RayMissingError
    from nuav2.maptr.infos import MissingCameraError, export_infos

    args.version = require_database(args.dataroot, args.version)
    check_infos_flags(args)
    check_cameras(args.dataroot, args.version, args.cameras)
    try:
        with diagnosed_tables(args.dataroot, args.version):
            written = export_infos(
                args.dataroot,
                args.version,
                args.out,
                args.prefix,
                args.splits,
                args.max_sweeps,
                tuple(args.patch),
                args.path_root,
                cameras=args.cameras,
                workers=args.workers,
                executor=args.executor,
                ray_address=args.ray_address,
                progress=not args.no_progress,
            )
    except RayMissingError as e:
        raise UsageError(str(e)) from e
    except MissingCameraError as e:
        raise UsageError(f"--cameras: {e}" if args.cameras else str(e)) from e
    print(json.dumps({split: str(path) for split, path in written.items()}, indent=1))
    # MapTR's own tools run in an older stack where nuav2 is not installed; this lets them open the maps.
    print(f"MapTR's tools (nuscenes-devkit 1.1.x) open the av2-* map locations with PYTHONPATH={HOOK_DIR}",
          file=sys.stderr)
    return 0
