"""``nuav2 bench recon``: reconstruction speed against target-rig error on a synthetic log, as JSON."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from nuav2.cli import group


def register(subparsers: argparse._SubParsersAction) -> None:
    sub = group("bench", "benchmarks")
    p = sub.add_parser("recon", help="reconstruction budgets vs target-rig PSNR/SSIM against ground truth",
                       description="Generates the default synthetic log (or reads LOG_DIR, a synthetic log), "
                                   "reconstructs it under several budgets (iterations x Gaussians x training "
                                   "resolution) and scores each in the nuScenes rig against the synthetic "
                                   "world's exact renders, plus held-out source-view PSNR and lane-paint "
                                   "alignment. Ratios are against the cheapest budget of the same run.")
    p.add_argument("log_dir", type=Path, nargs="?", default=None, help="a synthetic log directory")
    p.add_argument("--seed", type=int, default=0, help="synthetic world seed when generating")
    p.add_argument("--budgets", default=None,
                   help="comma-separated budget names (default: all of them)")
    p.add_argument("--holdout-every", type=int, default=5, help="hold out every k-th source image per camera")
    p.add_argument("--times", type=int, default=6, help="sample times scored in the target rig")
    p.add_argument("--out", type=Path, default=None, help="also write the JSON here")
    p.add_argument("--plot", type=Path, default=None, help="also write a PNG plot (PSNR against time) here")
    p.add_argument("--progress", action="store_true", help="show progress bars on stderr")
    p.add_argument("--json", action="store_true", help="compact JSON on one line (the default is indented)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from nuav2.atomic import atomic_write_json
    from nuav2.bench.recon import bench_recon, default_budgets, plot_bench

    budgets = default_budgets()
    if args.budgets:
        names = [b.strip() for b in args.budgets.split(",") if b.strip()]
        known = {b["name"] for b in budgets}
        unknown = sorted(set(names) - known)
        if unknown:
            raise SystemExit(f"unknown budget(s) {unknown}; known: {sorted(known)}")
        budgets = [b for b in budgets if b["name"] in names]
    result = bench_recon(args.log_dir, seed=args.seed, budgets=budgets, holdout_every=args.holdout_every,
                         n_times=args.times, progress=args.progress)
    if args.out is not None:
        atomic_write_json(args.out, result, indent=1)
    if args.plot is not None:
        plot_bench(result, args.plot)
    print(json.dumps(result, indent=None if args.json else 1))
    return 0
