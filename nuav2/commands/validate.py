"""``nuav2 validate DATAROOT --version V``: conformance check of a nuScenes database (exit 1 on problems)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from nuav2.cli_types import non_negative_int, path
from nuav2.nuscenes_db.validate import DEFAULT_MAX_PER_KIND, validate_database


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "validate", help="check a nuScenes database against what nuscenes-devkit and MapTR need",
        description="Exit 0 with per-table counts if DATAROOT/VERSION conforms, else 1 with every problem "
                    "grouped by table (at most --max-per-kind of each kind listed).")
    p.add_argument("dataroot", type=path, help="nuScenes dataroot (holds VERSION/, samples/, sweeps/, maps/)")
    p.add_argument("--version", help="table folder under DATAROOT, e.g. v1.0-trainval (default: the only one "
                                     "there)")
    p.add_argument("--no-files", action="store_true", help="skip sample_data files and map PNGs")
    p.add_argument("--no-images", action="store_true", help="skip reading JPEG headers for width/height")
    p.add_argument("--decode-images", action="store_true",
                   help="also decode every image to its end (finds truncated JPEGs; ~3 ms per AV2 image)")
    p.add_argument("--devkit", action="store_true", help="also instantiate NuScenes() and NuScenesMap()")
    p.add_argument("--max-per-kind", type=non_negative_int, default=DEFAULT_MAX_PER_KIND,
                   help="problems listed per (table, field, check) kind (>= 0); all are counted")
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    p.add_argument("--quiet", action="store_true", help="no progress bar (shown only on a terminal anyway)")
    p.set_defaults(func=run)


def require_version_folder(dataroot: Path, version: str) -> None:
    """A missing DATAROOT or VERSION folder is bad input (one line, exit 2), as for every command; what
    is inside a folder that exists (a missing table included) is the report's business (exit 1)."""
    from nuav2.cli import UsageError, versions_in

    if not dataroot.is_dir():
        why = "is not a directory" if dataroot.exists() else "not found"
        raise UsageError(f"{dataroot}: dataroot {why}")
    if version in ("", ".", "..") or Path(version).name != version:
        raise UsageError(f"--version {version!r}: must name a folder directly under DATAROOT")
    if not (dataroot / version).is_dir():
        raise UsageError(f"--version {version}: no folder {dataroot / version} "
                         f"(versions in {dataroot}: {', '.join(versions_in(dataroot)) or 'none'})")


def run(args: argparse.Namespace) -> int:
    from nuav2.cli import resolve_version

    args.version = resolve_version(args.dataroot, args.version)
    require_version_folder(args.dataroot, args.version)
    report = validate_database(args.dataroot, args.version, check_files=not args.no_files,
                               check_images=not args.no_images, decode_images=args.decode_images,
                               devkit=args.devkit,
                               max_per_kind=args.max_per_kind,
                               progress=not args.quiet and sys.stderr.isatty())
    print(json.dumps(report.to_json(), indent=1) if args.json else report.format_text())
    return 0 if report.ok else 1
