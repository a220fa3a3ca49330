"""``nuav2 bench scale --json``: logs per hour with local processes and with Ray at 1 and 2 workers."""

from __future__ import annotations

import argparse
import json
import os

from nuav2.bench.cli_args import synth_image_scale, synth_seconds
from nuav2.cli import group
from nuav2.cli_types import positive_float, positive_int


def register(subparsers: argparse._SubParsersAction) -> None:
    sub = group("bench", "benchmarks")
    p = sub.add_parser(
        "scale",
        help="conversion logs/hour: local processes vs Ray, 1 and 2 workers; Ray's overhead per task",
        description="Generates synthetic AV2 logs, then converts them with every executor and worker count "
                    "(interleaved, the fastest of --repeats counts), per mode. Needs nuav2[ray].",
    )
    p.add_argument("--logs", type=positive_int, default=4,
                   help="synthetic logs to convert, >= 1 (default: %(default)s)")
    p.add_argument("--seconds", type=synth_seconds, default=2.0,
                   help="length of each log, > 0.05 (10 sweeps/s; default: %(default)s)")
    p.add_argument("--image-scale", type=synth_image_scale, default=0.125,
                   help="source camera resolution factor vs AV2, > 0 (default: %(default)s)")
    p.add_argument("--scale", type=positive_float, default=0.125,
                   help="warp: target rig resolution factor, > 0 (default: %(default)s)")
    p.add_argument("--modes", nargs="+", default=["native", "warp"], choices=["native", "warp", "render"])
    p.add_argument("--repeats", type=positive_int, default=2,
                   help="interleaved repeats, >= 1; the fastest counts (default: %(default)s)")
    p.add_argument("--json", action="store_true", help="print compact JSON (the default is indented JSON)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from nuav2.bench.scale import bench_scale

    load = os.getloadavg()
    result = bench_scale(logs=args.logs, seconds=args.seconds, image_scale=args.image_scale,
                         warp_scale=args.scale, modes=tuple(args.modes), repeats=args.repeats)
    result["load_before"] = [round(x, 2) for x in load]
    result["load_after"] = [round(x, 2) for x in os.getloadavg()]
    print(json.dumps(result, indent=None if args.json else 1))
    return 0
