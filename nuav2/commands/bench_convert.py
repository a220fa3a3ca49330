"""``nuav2 bench convert --json``: native conversion frames/s vs a bare av2-loader read, as JSON."""

from __future__ import annotations

import argparse
import json

from nuav2.bench.cli_args import synth_image_scale, synth_seconds
from nuav2.cli import group
from nuav2.cli_types import positive_float, positive_int


def register(subparsers: argparse._SubParsersAction) -> None:
    sub = group("bench", "benchmarks")
    p = sub.add_parser(
        "convert",
        help="native AV2 -> nuScenes conversion throughput (frames/s) vs the av2 loader",
        description="Generates a synthetic AV2 log, then times AV2SensorDataLoader reading every sweep and "
                    "image against `convert av2 --mode native` of the same log, in the same process.",
    )
    p.add_argument("--seconds", type=synth_seconds, default=3.0,
                   help="length of the synthetic log, > 0.05 (10 sweeps/s)")
    p.add_argument("--image-scale", type=synth_image_scale, default=0.25,
                   help="camera resolution factor vs AV2, > 0")
    p.add_argument("--image-link", choices=["copy", "hardlink", "symlink"], default="copy")
    p.add_argument("--keyframe-hz", type=positive_float, default=None,
                   help="sample rate, > 0 (default: every sweep)")
    p.add_argument("--repeats", type=positive_int, default=2, help="runs per side, >= 1; the fastest counts")
    p.add_argument("--json", action="store_true", help="print compact JSON (the default is indented JSON)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from nuav2.bench.convert import bench_convert

    result = bench_convert(seconds=args.seconds, image_scale=args.image_scale, image_link=args.image_link,
                           keyframe_hz=args.keyframe_hz, repeats=args.repeats)
    print(json.dumps(result, indent=None if args.json else 1))
    return 0
