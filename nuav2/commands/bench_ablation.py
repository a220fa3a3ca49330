"""``nuav2 bench ablation --json``: what each realism factor costs warp and render mode (realism.md)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from nuav2.bench.cli_args import synth_image_scale, synth_seconds
from nuav2.cli import group
from nuav2.cli_types import non_negative_float, path, positive_float


def _speed_seconds(text: str) -> float:
    """``--speed-seconds``: 0 (skip the measurement) or a synthetic log length (> 0.05 s)."""
    value = non_negative_float(text)
    return value if value == 0 else synth_seconds(text)


def register(subparsers: argparse._SubParsersAction) -> None:
    p = group("bench", "benchmarks").add_parser(
        "ablation",
        help="realism ablation: the dB each synthetic-world factor costs warp and render mode",
        description="Starting from the easy synthetic world, switches each realism factor on alone (and "
                    "runs the medium and hard presets whole), converts each log in warp and render mode and "
                    "scores the written images against the world's exact renders: PSNR / SSIM over the whole "
                    "image and the ground, lane-paint offset, seconds; plus the synthetic world's speed per "
                    "preset (see docs/realism.md).")
    p.add_argument("--seeds", default="0,1", help="world seeds (each >= 0), comma-separated")
    p.add_argument("--factors", default="all",
                   help="factors to add one at a time (default: all; '' for none, the easy row and the "
                        "presets only; exposure_gains = exposure's gains without its sensor noise)")
    p.add_argument("--presets", default="medium,hard", help="whole presets to run too ('' for none)")
    p.add_argument("--seconds", type=synth_seconds, default=2.0, help="log length in seconds, > 0.05")
    p.add_argument("--image-scale", type=synth_image_scale, default=0.125,
                   help="AV2 camera resolution of the logs, > 0")
    p.add_argument("--rig", default="nuscenes", help="target rig name or JSON path")
    p.add_argument("--scale", type=positive_float, default=0.125, help="target rig resolution factor, > 0")
    p.add_argument("--recon-preset", choices=["default", "fast"], default="fast",
                   help="reconstruction settings for render mode (default: the fastest)")
    p.add_argument("--modes", default="warp,render", help="conversion modes to score")
    p.add_argument("--speed-seconds", type=_speed_seconds, default=2.0,
                   help="log length of the synth speed measurement per preset, > 0.05 (0: skip)")
    p.add_argument("--pictures", type=path, default=None,
                   help="write realism_<preset>.png (source | truth | warp | render) into this directory")
    p.add_argument("--work-dir", type=path, default=None, help="keep the logs and databases here")
    p.add_argument("--out", type=path, default=None, help="also write the JSON here")
    p.add_argument("--markdown", type=path, default=None, help="also write the docs' tables here")
    p.add_argument("--from-json", type=path, nargs="+", default=None,
                   help="do not run: read saved results (--out) and write --markdown from them; with several "
                        "files, each later one's modes replace the earlier ones' (e.g. a --modes warp rerun)")
    p.add_argument("--before", type=path, default=None,
                   help="a saved earlier result (--out): --markdown then also compares the two, factor by "
                        "factor, with the robustness goals (nuav2/bench/ablation_compare.py)")
    p.add_argument("--progress", action="store_true", help="show progress bars on stderr")
    p.add_argument("--json", action="store_true", help="compact JSON on one line (the default is indented)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from nuav2.atomic import atomic_write_bytes, atomic_write_json
    from nuav2.bench.ablation import ABLATION_FACTORS, AblationOptions, bench_ablation, markdown_table
    from nuav2.bench.cli_args import check_rig, command_line, parse_ints, require_outputs
    from nuav2.cli import UsageError
    from nuav2.synth import PRESETS

    require_outputs(args)
    before = None
    if args.before is not None:  # read first: a bad file fails before the long run
        from nuav2.bench.ablation_compare import compare_markdown, goals

        try:
            before = json.loads(Path(args.before).read_text())
        except (OSError, json.JSONDecodeError) as e:
            raise UsageError(f"--before {args.before}: cannot read a saved result ({e})") from e
    if args.from_json is not None:
        from nuav2.bench.ablation_compare import merge_modes

        saved = []
        for path in args.from_json:
            try:
                saved.append(json.loads(Path(path).read_text()))
            except (OSError, json.JSONDecodeError) as e:
                raise UsageError(f"--from-json {path}: cannot read a saved result ({e})") from e
        try:
            result = merge_modes(saved)
        except (KeyError, ValueError) as e:
            raise UsageError(f"--from-json: the files do not merge ({e})") from e
    else:
        seeds = parse_ints(args.seeds, "--seeds")
        factors = (ABLATION_FACTORS if args.factors == "all"
                   else tuple(f.strip() for f in args.factors.split(",") if f.strip()))
        presets = tuple(p.strip() for p in args.presets.split(",") if p.strip())
        modes = tuple(m.strip() for m in args.modes.split(",") if m.strip())
        for flag, got, known in (("--factors", factors, ABLATION_FACTORS), ("--presets", presets, PRESETS),
                                 ("--modes", modes, ("warp", "render"))):
            bad = [x for x in got if x not in known]
            if bad:
                raise UsageError(f"{flag}: unknown {', '.join(bad)}; known: {', '.join(known)}")
        check_rig(args.rig)
        opts = AblationOptions(seeds=seeds, factors=factors, presets=presets, seconds=args.seconds,
                               image_scale=args.image_scale, rig=args.rig, scale=args.scale,
                               recon_preset=args.recon_preset, modes=modes, speed_seconds=args.speed_seconds,
                               pictures=args.pictures, work_dir=args.work_dir, command=command_line(),
                               progress=args.progress)
        result = bench_ablation(opts)
        if args.out is not None:
            atomic_write_json(args.out, result, indent=1)
    if before is not None:
        result = {**result, "goals": goals(before, result)}
    if args.markdown is not None:
        text = markdown_table(result)
        if before is not None:
            text += "\n" + compare_markdown(before, result)
        atomic_write_bytes(args.markdown, text.encode())
    print(json.dumps(result, indent=None if args.json else 1))
    return 0
