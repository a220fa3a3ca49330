"""One reconstruction of a saved synthetic log (`--preset fast` or `default`), scored in the nuScenes rig.

Prints one JSON line: iterations run and why they stopped, Gaussians, seeding and total wall and CPU
seconds (CPU of all threads: the process's CPU time), source-image files decoded, and target-rig PSNR per
region over 12 sample times against the world's exact render. Run it once per checkout
(``git worktree add DIR COMMIT``) on the same log, one after another on a quiet machine, to compare
checkouts; a fresh checkout's first run also compiles its kernels, so run it twice there and keep the
second:

    nuav2 synth --seed 0 --preset easy --seconds 15 LOGS
    PYTHONPATH=DIR python docs/ablation/recon_long_log.py LOGS/train/<log_id>

``--device cuda`` trains and renders on the GPU with gsplat (the GPU figure in docs/cluster.md);
CPU seconds then count the host threads only.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

from converters.av2 import read_log
from nuav2.bench.recon import DEFAULT_TARGET_SCALE, target_rig_scores
from nuav2.bench.timing import Stopwatch
from nuav2.recon import ReconConfig, default_channels, reconstruct
from nuav2.splat.views import source_views
from nuav2.synth import load_world


def count_source_decodes() -> list[int]:
    """Count the source-image files the reconstruction decodes (one-element list, updated in place)."""
    import nuav2.splat.views as views_module

    count = [0]
    load = views_module.load_image_u8

    def counted(*args, **kwargs):
        count[0] += 1
        return load(*args, **kwargs)

    views_module.load_image_u8 = counted
    return count


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("log_dir", type=Path, help="a synthetic AV2 log folder (nuav2 synth)")
    ap.add_argument("--times", type=int, default=12, help="sample times scored in the nuScenes rig")
    ap.add_argument("--preset", default="fast", choices=("fast", "default"), help="reconstruction preset")
    ap.add_argument("--half-res-iterations", type=int, default=None,
                    help="half-resolution iterations (default: the preset's fraction of the cap)")
    ap.add_argument("--device", default="cpu", help="cpu (default), cuda or auto (see nuav2.recon)")
    ap.add_argument("--patience", type=int, default=None,
                    help="the early-stop rule's patience (0: never stop early; default: the preset's)")
    ap.add_argument("--iterations-per-view", type=float, default=None,
                    help="the cap's iterations per training image (default: the preset's)")
    ap.add_argument("--lambda-flat", type=float, default=None,
                    help="weight of the background's flatness loss (0: off; default: the preset's)")
    ap.add_argument("--structure-merge-levels", type=int, default=None,
                    help="levels of the plain structure merge (0: off; default: the preset's)")
    ap.add_argument("--cooldown-frac", type=float, default=None,
                    help="cool-down after a plateau, a fraction of the steps run (0: off; default: preset)")
    ap.add_argument("--cooldown-lr-end", type=float, default=None,
                    help="the other learning rates' factor at the cool-down's end (default: the preset's)")
    ap.add_argument("--cooldown-frozen-positions", action="store_true",
                    help="the cool-down keeps the position and sky LR where the plateau left them (with "
                         "--cooldown-lr-end 1: plain extra steps, the control)")
    ap.add_argument("--scale", type=float, default=DEFAULT_TARGET_SCALE, help="nuScenes rig scale scored")
    args = ap.parse_args()
    scene, world = read_log(args.log_dir), load_world(args.log_dir)
    cfg = replace(ReconConfig.preset(args.preset), device=args.device)
    train_flags = {"patience": args.patience, "lambda_flat": args.lambda_flat,
                   "cooldown_frac": args.cooldown_frac, "cooldown_lr_end": args.cooldown_lr_end,
                   "iterations_per_view": args.iterations_per_view,
                   "cooldown_positions": False if args.cooldown_frozen_positions else None}
    cfg = replace(cfg, train=replace(cfg.train, **{k: v for k, v in train_flags.items() if v is not None}))
    if args.structure_merge_levels is not None:
        budget = replace(cfg.init.budget, structure_merge_levels=args.structure_merge_levels)
        cfg = replace(cfg, init=replace(cfg.init, budget=budget))
    if args.half_res_iterations is not None:  # the coarse stage as a count, not a fraction of the cap
        views = source_views(scene, cfg.scale_for(scene), channels=default_channels(scene))
        n_train = len(views) // cfg.frame_stride
        cap = cfg.train.for_views(n_train).iterations
        cfg = replace(cfg, train=replace(cfg.train, pyramid_until=(args.half_res_iterations / cap,)))
    decodes = count_source_decodes()
    sw = Stopwatch()
    with sw:
        splat = reconstruct(scene, cfg, progress=False)
    train = splat.info["train"]
    target = target_rig_scores(splat, scene, world, scale=args.scale, n_times=args.times)
    regions = target["regions"]["psnr_db"]
    print(json.dumps({
        "log": scene.log_id, "preset": args.preset, "device": splat.info["device"],
        "half_res_iterations": args.half_res_iterations, "patience": cfg.train.patience,
        "iterations_per_view": getattr(cfg.train, "iterations_per_view", None),
        "lambda_flat": getattr(cfg.train, "lambda_flat", None),
        "cooldown_frac": cfg.train.cooldown_frac, "cooldown_lr_end": cfg.train.cooldown_lr_end,
        "cooldown_positions": cfg.train.cooldown_positions, "cooldown": train.get("cooldown"),
        "structure_merge_levels": cfg.init.budget.structure_merge_levels if cfg.init.budget else None,
        "iterations_cap": train.get("iterations"), "steps": train["steps"],
        "stop_reason": train["stop_reason"], "densify_stopped_at": train["densify_stopped_at"],
        "last_heldout_psnr_db": train["validation"][-1][1] if train["validation"] else None,
        "gaussians": splat.num_gaussians(), "seeding_s": round(splat.info["init_seconds"], 1),
        "source_decodes": decodes[0],
        "recon_wall_s": round(sw.wall_s[0], 1), "recon_cpu_s": round(sw.cpu_s[0], 1), "load_1min": sw.load[0],
        "psnr_db": round(target["psnr_db"], 3), "ssim": round(target["ssim"], 4),
        **{f"psnr_{k}_db": round(v, 3) for k, v in regions.items() if v is not None}}))


if __name__ == "__main__":
    main()
