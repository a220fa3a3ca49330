"""``nuav2 demo``: the whole pipeline on the built-in synthetic scene, per realism preset."""

from __future__ import annotations

import argparse
from pathlib import Path

from nuav2.cli_types import path

DEMO_MODES = ("render", "warp", "native")


def _run(args: argparse.Namespace) -> int:
    from nuav2.bench.cli_args import parse_presets
    from nuav2.commands.convert import refuse_other_mode_flags
    from nuav2.demo import DemoOptions, format_summary, run_demo

    presets = tuple(parse_presets(args.preset))  # a bad value: one line from nuav2.cli
    refuse_other_mode_flags(args, DEMO_MODES)  # --rig with --mode native, ...: refused as convert does
    given = {name: getattr(args, name) for name in ("rig", "scale", "recon_preset")
             if getattr(args, name) is not None}
    # run_demo checks --rig (and the rest) before it synthesises anything
    summary = run_demo(DemoOptions(out=args.out, seed=args.seed, mode=args.mode, presets=presets,
                                   seconds=args.seconds, progress=not args.no_progress, **given))
    print(format_summary(summary))
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    from nuav2.bench.cli_args import synth_seconds
    from nuav2.cli_types import non_negative_int, positive_float

    p = subparsers.add_parser(
        "demo", help="run the whole pipeline on the built-in synthetic scene",
        description="Synthesise an AV2 log, convert it into a nuScenes database re-rendered in the target "
                    "rig, validate it, load it with the devkit, score it against ground truth (whole image, "
                    "ground, objects, sky, lane paint) and write a side-by-side PNG; per realism preset, "
                    "into OUT/<preset>/, the presets side by side in OUT/demo_summary.json. The demo owns "
                    "OUT/<preset>/: a rerun with other options (seed, mode, rig, scale, recon preset, "
                    "seconds) replaces the previous run's synthetic log (av2/) and database (nuscenes/) "
                    "there; a rerun with the same options reuses the converted log. Smallest run: "
                    "--mode warp --scale 0.1 --seconds 0.3.")
    p.add_argument("--out", type=path, default=Path("nuav2_demo"),
                   help="output directory (default: %(default)s)")
    p.add_argument("--seed", type=non_negative_int, default=0, help="world seed, >= 0 (default: %(default)s)")
    p.add_argument("--preset", default="easy",
                   help="synthetic realism preset(s): easy,medium,hard or all (default: %(default)s)")
    p.add_argument("--mode", choices=DEMO_MODES, default="render",
                   help="render: Gaussian splatting (default); warp: fast depth warp; native: AV2 cameras")
    # defaults None, so that one given with --mode native is refused; DemoOptions holds the real ones
    p.add_argument("--rig", default=None,
                   help="warp / render: target rig name or JSON path (default: nuscenes)")
    p.add_argument("--scale", type=positive_float, default=None,
                   help="warp / render: target resolution factor, > 0 (default: 0.25)")
    p.add_argument("--recon-preset", choices=["default", "fast"], default=None,
                   help="render mode's reconstruction budget (default: fast)")
    p.add_argument("--seconds", type=synth_seconds, default=2.0,
                   help="seconds of synthetic driving, > 0.05 (default: %(default)s)")
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=_run)
