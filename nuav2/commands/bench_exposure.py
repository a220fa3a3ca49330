"""``nuav2 bench exposure --json``: warp mode's exposure solve against the synthetic cameras' true gains."""

from __future__ import annotations

import argparse
import json

from nuav2.bench.cli_args import synth_seconds
from nuav2.cli import group
from nuav2.cli_types import non_negative_int, path, positive_int


def register(subparsers: argparse._SubParsersAction) -> None:
    p = group("bench", "benchmarks").add_parser(
        "exposure",
        help="exposure solve: error against the true gains and CPU time, per variant",
        description="Generates a synthetic log with camera exposure effects, solves warp mode's source "
                    "exposure with and without leaving labelled actors out and with and without the "
                    "per-point observation cap, and scores each against the world's clean renders of a "
                    "sample of source images (see docs/reconstruction.md).")
    p.add_argument("--preset", default="hard", help="realism preset with exposure effects (default: hard)")
    p.add_argument("--seconds", type=synth_seconds, default=15.0,
                   help="log length in seconds, > 0.05 (default: 15)")
    p.add_argument("--seed", type=non_negative_int, default=0, help="world seed, >= 0")
    p.add_argument("--sample", type=positive_int, default=120,
                   help="source images scored, >= 1 (default: 120)")
    p.add_argument("--work-dir", type=path, default=None,
                   help="keep the log here (a later run with the same settings reuses it)")
    p.add_argument("--out", type=path, default=None, help="also write the JSON here")
    p.add_argument("--markdown", type=path, default=None, help="also write the docs' table here")
    p.add_argument("--json", action="store_true", help="compact JSON on one line (the default is indented)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from nuav2.atomic import atomic_write_bytes, atomic_write_json
    from nuav2.bench.cli_args import command_line, require_outputs
    from nuav2.bench.exposure import bench_exposure, markdown_table
    from nuav2.cli import UsageError
    from nuav2.synth import PRESETS

    require_outputs(args)
    if args.preset not in PRESETS:
        raise UsageError(f"--preset {args.preset!r}: must be one of {', '.join(PRESETS)}")
    try:
        result = bench_exposure(args.preset, args.seconds, args.seed, args.sample, args.work_dir)
    except ValueError as e:
        raise UsageError(str(e)) from e
    result["command"] = command_line()
    if args.out is not None:
        atomic_write_json(args.out, result, indent=1)
    if args.markdown is not None:
        atomic_write_bytes(args.markdown, markdown_table(result, result["command"]).encode())
    print(json.dumps(result, indent=None if args.json else 1))
    return 0
