"""``nuav2 bench eval``: vectorised chamfer AP against the per-sample reference, same data, same run."""

from __future__ import annotations

import argparse
import json


def _run(args: argparse.Namespace) -> int:
    from nuav2.bench.eval import run_eval_benchmark

    result = run_eval_benchmark(n_samples=args.samples, seed=args.seed, skip_reference=args.skip_reference)
    print(json.dumps(result) if args.json else json.dumps(result, indent=2))
    return 0


def register(subparsers) -> None:
    from nuav2.cli import group
    from nuav2.cli_types import non_negative_int, positive_int

    p = group("bench", "benchmarks").add_parser(
        "eval", help="chamfer-AP evaluation speed vs the per-sample reference (synthetic MapTR-like data)"
    )
    p.add_argument(
        "--samples", type=positive_int, default=6000,
        help="synthetic samples, >= 1 (default 6000, a full val set)"
    )
    p.add_argument("--seed", type=non_negative_int, default=0, help="data seed, >= 0 (default 0)")
    p.add_argument("--skip-reference", action="store_true", help="time only the vectorised evaluator")
    p.add_argument("--json", action="store_true", help="one JSON line instead of indented JSON")
    p.set_defaults(func=_run)
