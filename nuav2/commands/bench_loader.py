"""``nuav2 bench loader [DATAROOT] [--version V]``: MapTR loader throughput with GT extraction, as JSON."""

from __future__ import annotations

import argparse
import json

from nuav2.bench.cli_args import synth_image_scale, synth_seconds
from nuav2.cli import group, require_database
from nuav2.cli_types import path, positive_float, positive_int

SYNTHETIC_VERSION = "v1.0-nuav2"


def register(subparsers: argparse._SubParsersAction) -> None:
    sub = group("bench", "benchmarks")
    p = sub.add_parser(
        "loader",
        help="MapTR-style dataset throughput (samples/s, map GT included)",
        description="Times MapSampleDataset items (images, poses, vectorized GT, fixed-point "
        "targets) against a bare devkit lookup + JPEG decode of the same keyframes.",
    )
    p.add_argument(
        "dataroot",
        type=path,
        nargs="?",
        default=None,
        help="nuScenes-format dataroot (default: convert a fresh synthetic AV2 log)",
    )
    p.add_argument("--version", default=None,
                   help="table folder under DATAROOT (default: the only one there; "
                   f"{SYNTHETIC_VERSION} for the synthetic log)")
    p.add_argument("--split", default=None,
                   help="split to read (default: the alphabetically first in splits.json, usually all)")
    p.add_argument("--samples", type=positive_int, default=50, help="keyframes to time, >= 1")
    p.add_argument("--image-scale", type=positive_float, default=1.0,
                   help="resize images by this factor, > 0")
    p.add_argument(
        "--synthetic-seconds",
        type=synth_seconds,
        default=2.0,
        help="length of the synthetic log when no DATAROOT is given, > 0.05",
    )
    p.add_argument(
        "--synthetic-image-scale",
        type=synth_image_scale,
        default=0.125,
        help="AV2 camera resolution factor of the synthetic log, > 0",
    )
    p.add_argument("--json", action="store_true", help="print JSON only (the default output is JSON too)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from nuav2.bench.loader import bench_loader, synthetic_dataroot

    if args.dataroot is not None:
        version = require_database(args.dataroot, args.version)
        result = bench_loader(args.dataroot, version, args.split, args.samples, args.image_scale)
    else:
        version = args.version or SYNTHETIC_VERSION
        with synthetic_dataroot(args.synthetic_seconds, args.synthetic_image_scale, version) as root:
            result = bench_loader(root, version, args.split, args.samples, args.image_scale)
    print(json.dumps(result, indent=None if args.json else 1))
    return 0
