"""``nuav2 bench raster``: our CPU rasterizer against gsplat's PyTorch path, interleaved, as JSON."""

from __future__ import annotations

import argparse
import json

from nuav2.cli import UsageError, group
from nuav2.cli_types import non_negative_int, positive_int


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"image size must look like 480x270, got {text!r}") from None
    if w <= 0 or h <= 0:
        raise argparse.ArgumentTypeError(f"image size must be positive, got {text!r}")
    return w, h


SCENES = ("near_splats", "street")          # nuav2.bench.raster.SCENES (not imported here: torch is slow)


def register(subparsers: argparse._SubParsersAction) -> None:
    sub = group("bench", "benchmarks")
    p = sub.add_parser(
        "raster",
        help="Gaussian rasterizer fwd+bwd: ours vs gsplat's PyTorch path on CPU, per stage, vs the floor",
        description="Renders two synthetic scenes (a street; seeded near, big splats at 2-80 m) with "
        "nuav2.splat.rasterize on 1 and on all threads, and with gsplat's own PyTorch rendering on "
        "the CPU when gsplat is installed, interleaved step by step in one process. Reports wall and "
        "CPU time, load, peak memory, the image difference, per-stage times, and Gaussian-pixel "
        "contributions against the machine's measured exp+FMA rate (fraction of the roofline).",
    )
    p.add_argument("--quick", action="store_true", help="small sizes only: 240x135/10k and 480x270/30k")
    p.add_argument("--scenes", nargs="+", choices=sorted(SCENES), default=None, help="scenes (default: both)")
    p.add_argument("--sizes", type=_size, nargs="+", default=None, metavar="WxH",
                   help="image sizes, each paired with every --counts (default 480x270/100k, 960x540/100k, "
                   "1600x900/300k)")
    p.add_argument("--counts", type=positive_int, nargs="+", default=None, metavar="N",
                   help="Gaussian counts, each >= 1")
    p.add_argument("--repeats", type=positive_int, default=5,
                   help="interleaved rounds per case, >= 1 (min and median)")
    p.add_argument("--no-gsplat", action="store_true", help="skip gsplat's PyTorch reference")
    p.add_argument("--gsplat-max-contributions", type=non_negative_int, default=None, metavar="N",
                   help="skip gsplat's reference on cases with more Gaussian-pixel contributions than this "
                   "(it holds them all in memory, about 200 B each; default 20,000,000)")
    p.add_argument("--json", action="store_true", help="compact one-line JSON (default: indented)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from nuav2.bench.raster import GSPLAT_MAX_CONTRIBUTIONS, default_cases, run_raster_bench

    scenes = args.scenes or sorted(SCENES)
    if args.sizes or args.counts:
        if not (args.sizes and args.counts):
            raise UsageError("--sizes and --counts go together: give both or neither")
        cases = [(s, w, h, n) for s in scenes for w, h in args.sizes for n in args.counts]
    else:
        cases = default_cases(args.quick, scenes)
    budget = args.gsplat_max_contributions
    if budget is None:
        budget = GSPLAT_MAX_CONTRIBUTIONS
    result = run_raster_bench(cases, repeats=args.repeats, reference=not args.no_gsplat,
                              max_contributions=budget)
    print(json.dumps(result, indent=None if args.json else 1))
    return 0
