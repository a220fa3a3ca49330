"""``nuav2 demo``: the whole pipeline on the built-in synthetic scene, per realism preset."""

from __future__ import annotations

import argparse
from pathlib import Path


def _run(args: argparse.Namespace) -> int:
    from nuav2.bench.cli_args import parse_presets
    from nuav2.demo import DemoOptions, format_summary, run_demo

    presets = tuple(parse_presets(args.preset))  # a bad value: one line from nuav2.cli
    summary = run_demo(DemoOptions(out=args.out, seed=args.seed, mode=args.mode, rig=args.rig,
                                   scale=args.scale, recon_preset=args.recon_preset, presets=presets,
                                   seconds=args.seconds, progress=not args.no_progress))
    print(format_summary(summary))
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "demo", help="run the whole pipeline on the built-in synthetic scene",
        description="Synthesise an AV2 log, convert it into a nuScenes database re-rendered in the target "
                    "rig, validate it, load it with the devkit, score it against ground truth (whole image, "
                    "ground, objects, sky, lane paint) and write a side-by-side PNG; per realism preset, "
                    "into OUT/<preset>/, the presets side by side in OUT/demo_summary.json.")
    p.add_argument("--out", type=Path, default=Path("nuav2_demo"),
                   help="output directory (default: %(default)s)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--preset", default="easy",
                   help="synthetic realism preset(s): easy,medium,hard or all (default: %(default)s)")
    p.add_argument("--mode", choices=["render", "warp", "native"], default="render",
                   help="render: Gaussian splatting (default); warp: fast depth warp; native: AV2 cameras")
    p.add_argument("--rig", default="nuscenes", help="target rig (default: %(default)s)")
    p.add_argument("--scale", type=float, default=0.25,
                   help="target resolution factor (default: %(default)s)")
    p.add_argument("--recon-preset", default="fast", help="reconstruction budget (default: %(default)s)")
    p.add_argument("--seconds", type=float, default=2.0, help="seconds of synthetic driving")
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=_run)
