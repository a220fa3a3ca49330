"""``nuav2 bench raster``: CPU Gaussian rasterizer timings against the dense torch reference, as JSON."""

from __future__ import annotations

import argparse
import json

from nuav2.cli import group


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"image size must look like 480x270, got {text!r}") from None
    if w <= 0 or h <= 0:
        raise argparse.ArgumentTypeError(f"image size must be positive, got {text!r}")
    return w, h


def register(subparsers: argparse._SubParsersAction) -> None:
    sub = group("bench", "benchmarks")
    p = sub.add_parser(
        "raster",
        help="Gaussian rasterizer forward / forward+backward timings (CPU kernels vs dense reference)",
        description="Renders a synthetic street of Gaussians with nuav2.splat.rasterize and reports "
        "forward and forward+backward wall time, peak memory and the speed-up over the dense "
        "plain-torch reference (timed in the same run on a crop where it fits in memory).",
    )
    p.add_argument("--quick", action="store_true", help="only 240x135/10k and 480x270/100k")
    p.add_argument("--sizes", type=_size, nargs="+", default=None, metavar="WxH",
                   help="image sizes (default 240x135 480x270 960x540)")
    p.add_argument("--counts", type=int, nargs="+", default=None, metavar="N",
                   help="Gaussian counts (default 10000 100000 300000)")
    p.add_argument("--repeats", type=int, default=3, help="timed repetitions per case (median reported)")
    p.add_argument("--no-dense", action="store_true", help="skip the dense-reference comparison")
    p.add_argument("--json", action="store_true", help="compact one-line JSON (default: indented)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from nuav2.bench.raster import default_cases, run_raster_bench

    if args.repeats < 1:
        raise SystemExit("--repeats must be >= 1")
    if args.sizes or args.counts:
        base = default_cases(False)
        sizes = args.sizes or sorted({(w, h) for w, h, _ in base}, key=lambda s: s[0])
        counts = args.counts or sorted({n for _, _, n in base})
        if any(n < 0 for n in counts):
            raise SystemExit("--counts must be >= 0")
        cases = [(w, h, n) for w, h in sizes for n in counts]
    else:
        cases = default_cases(args.quick)
    result = run_raster_bench(cases, repeats=args.repeats, dense=not args.no_dense)
    print(json.dumps(result, indent=None if args.json else 1))
    return 0
