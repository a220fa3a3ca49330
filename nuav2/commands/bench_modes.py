"""``nuav2 bench modes``: rotation baseline vs warp vs render, interleaved: time per frame, region quality."""

from __future__ import annotations

import argparse
import json

from nuav2.bench.cli_args import synth_image_scale
from nuav2.cli import group
from nuav2.cli_types import path, positive_float, positive_int


def register(subparsers: argparse._SubParsersAction) -> None:
    p = group("bench", "benchmarks").add_parser(
        "modes",
        help="rotation baseline / warp / render: time per frame (wall + CPU, interleaved) and region quality",
        description="Generates synthetic AV2 logs (per realism preset and log length), renders the target "
                    "rig's cameras at every sweep with each candidate, frame by frame in turn, and scores "
                    "them against the synthetic world's exact images per region (see docs/modes.md).",
    )
    p.add_argument("--preset", default="easy", help="synthetic realism preset(s): easy,medium,hard or all")
    p.add_argument("--seconds", default="2",
                   help="log length(s) in seconds, each > 0.05, comma-separated (e.g. 2,15)")
    p.add_argument("--seeds", "--seed", dest="seeds", default="0",
                   help="synthetic scene seed(s), each >= 0, comma-separated (tables: mean ± std over them)")
    p.add_argument("--image-scale", type=synth_image_scale, default=None,
                   help="AV2 camera resolution factor of the synthetic log, > 0 (default: the preset's, 1/8)")
    p.add_argument("--rig", default="nuscenes", help="target rig name or JSON path")
    p.add_argument("--scale", type=positive_float, default=0.16, help="target rig resolution factor, > 0")
    p.add_argument("--frame-step", type=positive_int, default=1, help="use every k-th sweep as a frame, >= 1")
    p.add_argument("--no-render", action="store_true", help="skip the Gaussian-splat render mode")
    p.add_argument("--recon-preset", choices=["default", "fast"], default="fast",
                   help="reconstruction settings for render mode")
    p.add_argument("--work-dir", type=path, default=None, help="keep the synthetic logs here (default: temp)")
    p.add_argument("--out", type=path, default=None, help="also write the JSON here")
    p.add_argument("--markdown", type=path, default=None,
                   help="also write the docs' markdown tables (with how they were measured) here")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.add_argument("--json", action="store_true", help="compact JSON (default: indented)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from nuav2.atomic import atomic_write_json
    from nuav2.bench.cli_args import (
        check_rig,
        command_line,
        parse_floats,
        parse_ints,
        parse_presets,
        require_outputs,
    )
    from nuav2.bench.cli_args import synth_seconds as seconds_type
    from nuav2.bench.modes import bench_modes

    require_outputs(args)
    presets = parse_presets(args.preset)  # a bad value: one line from nuav2.cli, before any work
    seconds = parse_floats(args.seconds, "--seconds", seconds_type)
    seeds = parse_ints(args.seeds, "--seeds")
    check_rig(args.rig)
    result = bench_modes(presets, seconds, seeds, command=command_line(),
                         image_scale=args.image_scale, rig_name=args.rig, scale=args.scale,
                         frame_step=args.frame_step, with_render=not args.no_render,
                         recon_preset=args.recon_preset, work_dir=args.work_dir, progress=not args.quiet)
    if args.out is not None:
        atomic_write_json(args.out, result, indent=1)
    if args.markdown is not None:
        from nuav2.atomic import atomic_write_bytes
        from nuav2.bench.markdown import modes_markdown

        atomic_write_bytes(args.markdown, modes_markdown(result).encode())
    print(json.dumps(result, indent=None if args.json else 1))
    return 0
