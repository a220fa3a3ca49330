"""``nuav2 bench recon``: reconstruction speed against target-rig error on synthetic logs, as JSON."""

from __future__ import annotations

import argparse
import json

from nuav2.cli import UsageError, group
from nuav2.cli_types import number, path, positive_int


def register(subparsers: argparse._SubParsersAction) -> None:
    sub = group("bench", "benchmarks")
    p = sub.add_parser(
        "recon", help="reconstruction budgets vs target-rig PSNR/SSIM per region against ground truth",
        description="Generates synthetic logs (per realism preset and seed; or reads LOG_DIR, a synthetic "
                    "log), reconstructs each under several budgets (iterations x Gaussians x training "
                    "resolution) and scores each in the nuScenes rig against the synthetic world's exact "
                    "renders, per region (whole, ground, objects, sky), plus held-out source-view PSNR and "
                    "lane-paint alignment. Over several seeds it reports mean and spread, the seed the "
                    "presets were tuned on apart.")
    p.add_argument("log_dir", type=path, nargs="?", default=None, help="a synthetic log directory")
    p.add_argument("--preset", default="easy", help="synthetic realism preset(s): easy,medium,hard or all")
    p.add_argument("--seeds", default="0",
                   help="synthetic world seeds (each >= 0) when generating, comma-separated")
    p.add_argument("--scene", default=None,
                   help="scene variants on top of the preset, comma-separated: empty (a straight road, "
                        "no traffic), busy (the four-way junction, twice the traffic); default: the preset's")
    p.add_argument("--budgets", default=None,
                   help="comma-separated budget names (default: all of them)")
    p.add_argument("--holdout-every", type=number(int, lo=2), default=5,
                   help="hold out every k-th source image per camera, >= 2 (1 would hold out all)")
    p.add_argument("--times", type=positive_int, default=6,
                   help="sample times scored in the target rig, >= 1")
    p.add_argument("--out", type=path, default=None, help="also write the JSON here")
    p.add_argument("--markdown", type=path, default=None,
                   help="also write the docs' markdown tables (with how they were measured) here")
    p.add_argument("--plot", type=path, default=None, help="also write a PNG plot (PSNR against time) here")
    p.add_argument("--progress", action="store_true", help="show progress bars on stderr")
    p.add_argument("--json", action="store_true", help="compact JSON on one line (the default is indented)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from nuav2.atomic import atomic_write_json
    from nuav2.bench.cli_args import command_line, parse_ints, parse_presets, require_outputs
    from nuav2.bench.recon import SCENES, bench_recon, default_budgets, plot_bench

    require_outputs(args)
    budgets = default_budgets()
    presets = parse_presets(args.preset)  # a bad value: one line from nuav2.cli
    seeds = parse_ints(args.seeds, "--seeds")
    if args.budgets:
        names = [b.strip() for b in args.budgets.split(",") if b.strip()]
        known = {b["name"] for b in budgets}
        unknown = sorted(set(names) - known)
        if unknown:
            raise UsageError(f"--budgets: unknown budget(s) {unknown}; known: {sorted(known)}")
        budgets = [b for b in budgets if b["name"] in names]
    scenes: tuple[str | None, ...] = (None,)
    if args.scene:
        scenes = tuple(dict.fromkeys(s.strip() for s in args.scene.split(",") if s.strip()))
        unknown = sorted(set(scenes) - set(SCENES))
        if unknown or not scenes:
            raise UsageError(f"--scene: unknown scene(s) {unknown or [args.scene]}; known: {sorted(SCENES)}")
    result = bench_recon(args.log_dir, seeds=seeds, presets=tuple(presets), budgets=budgets,
                         holdout_every=args.holdout_every, n_times=args.times, scenes=scenes,
                         command=command_line(), progress=args.progress)
    if args.out is not None:
        atomic_write_json(args.out, result, indent=1)
    if args.markdown is not None:
        from nuav2.atomic import atomic_write_bytes
        from nuav2.bench.markdown import recon_markdown

        atomic_write_bytes(args.markdown, recon_markdown(result).encode())
    if args.plot is not None:
        plot_bench(result, args.plot)
    print(json.dumps(result, indent=None if args.json else 1))
    return 0
