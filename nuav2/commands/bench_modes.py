"""``nuav2 bench modes --json``: native vs warp vs render: time per frame and PSNR/SSIM vs ground truth."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from nuav2.cli import group


def register(subparsers: argparse._SubParsersAction) -> None:
    p = group("bench", "benchmarks").add_parser(
        "modes",
        help="native / warp / render: wall time per frame and target-rig PSNR/SSIM against ground truth",
        description="Generates the default synthetic AV2 log, renders the target rig's cameras at every "
                    "sample time with each mode, and scores them against the synthetic world's exact images "
                    "of the same cameras (see docs/modes.md).",
    )
    p.add_argument("--seed", type=int, default=0, help="synthetic scene seed")
    p.add_argument("--seconds", type=float, default=None, help="log length (default: SynthConfig's)")
    p.add_argument("--rig", default="nuscenes", help="target rig name or JSON path")
    p.add_argument("--scale", type=float, default=0.16, help="target rig resolution factor")
    p.add_argument("--frame-step", type=int, default=1, help="use every k-th sweep as a frame")
    p.add_argument("--no-render", action="store_true", help="skip the Gaussian-splat render mode")
    p.add_argument("--recon-preset", choices=["default", "fast"], default="default",
                   help="reconstruction settings for render mode")
    p.add_argument("--work-dir", type=Path, default=None, help="keep the synthetic log here (default: temp)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.add_argument("--json", action="store_true", help="compact JSON (default: indented)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from nuav2.bench.modes import bench_modes
    from nuav2.synth import SynthConfig

    config = SynthConfig() if args.seconds is None else SynthConfig(seconds=args.seconds)
    result = bench_modes(seed=args.seed, config=config, rig_name=args.rig, scale=args.scale,
                         frame_step=args.frame_step, with_render=not args.no_render,
                         recon_preset=args.recon_preset, work_dir=args.work_dir, progress=not args.quiet)
    print(json.dumps(result, indent=None if args.json else 1))
    return 0
