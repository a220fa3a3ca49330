"""``nuav2 bench scale --json``: logs per hour with local processes and with Ray at 1 and 2 workers."""

from __future__ import annotations

import argparse
import json
import os

from nuav2.cli import group


def register(subparsers: argparse._SubParsersAction) -> None:
    sub = group("bench", "benchmarks")
    p = sub.add_parser(
        "scale",
        help="conversion logs/hour: local processes vs Ray, 1 and 2 workers; Ray's overhead per task",
        description="Generates synthetic AV2 logs, then converts them with every executor and worker count "
                    "(interleaved, the fastest of --repeats counts), per mode. Needs nuav2[ray].",
    )
    p.add_argument("--logs", type=int, default=4, help="synthetic logs to convert (default: %(default)s)")
    p.add_argument("--seconds", type=float, default=2.0, help="length of each log (10 sweeps/s)")
    p.add_argument("--image-scale", type=float, default=0.125, help="source camera resolution factor vs AV2")
    p.add_argument("--scale", type=float, default=0.125, help="warp: target rig resolution factor")
    p.add_argument("--modes", nargs="+", default=["native", "warp"], choices=["native", "warp", "render"])
    p.add_argument("--repeats", type=int, default=2, help="interleaved repeats; the fastest counts")
    p.add_argument("--json", action="store_true", help="print compact JSON (the default is indented JSON)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from nuav2.bench.scale import bench_scale

    load = os.getloadavg()
    result = bench_scale(logs=max(1, args.logs), seconds=args.seconds, image_scale=args.image_scale,
                         warp_scale=args.scale, modes=tuple(args.modes), repeats=max(1, args.repeats))
    result["load_before"] = [round(x, 2) for x in load]
    result["load_after"] = [round(x, 2) for x in os.getloadavg()]
    print(json.dumps(result, indent=None if args.json else 1))
    return 0
