"""Does the early-stop signal follow the target rig? Held-out PSNR at half and at the training
resolution, against the nuScenes-rig PSNR, along one reconstruction that never stops early.

Every ``eval_every`` steps (100) the 8 validation images the patience rule measures are rendered at
half and at the training resolution (mean per-image PSNR, as the rule computes it); every
``--target-every`` steps the nuScenes rig is scored against the world's exact render (scale 0.16,
12 sample times). Writes one JSON:

    nuav2 synth --seed 0 --preset easy --seconds 15 LOGS      # and --preset hard
    python docs/ablation/heldout_resolution.py LOGS/train/<log_id> --out heldout_resolution.json
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import nuav2.splat.train as train_module
from converters.av2 import read_log
from nuav2.bench.recon import target_rig_scores
from nuav2.recon import ReconConfig, reconstruct
from nuav2.synth import load_world


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("log_dir", type=Path, help="a synthetic AV2 log folder (nuav2 synth)")
    ap.add_argument("--target-every", type=int, default=300, help="steps between nuScenes-rig scores")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    scene, world = read_log(args.log_dir), load_world(args.log_dir)
    cfg = ReconConfig.fast()
    cfg = replace(cfg, train=replace(cfg.train, patience=0))  # measure the whole cap
    rows: list[dict] = []
    check = train_module.Trainer._check_plateau

    def measured(trainer) -> None:
        check(trainer)
        if trainer.step % trainer.cfg.eval_every:
            return
        row = {"step": trainer.step, "mean0.5": trainer.validate(0.5),
               "mean1.0": trainer.validate(trainer.cfg.pyramid[-1])}
        if trainer.step % args.target_every == 0:
            s = target_rig_scores(trainer.splat, scene, world, scale=0.16, n_times=12, paint=False)
            row["target"], row["target_ground"] = s["psnr_db"], s["regions"]["psnr_db"]["ground"]
        rows.append({k: round(v, 3) if isinstance(v, float) else v for k, v in row.items()})
        print(json.dumps(rows[-1]), flush=True)

    train_module.Trainer._check_plateau = measured
    c0 = time.process_time()
    reconstruct(scene, cfg, progress=False)
    args.out.write_text(json.dumps({
        "what": "held-out PSNR of the validation images at half (mean0.5) and at the training resolution "
                "(mean1.0) every 100 steps, nuScenes-rig PSNR (scale 0.16, 12 times) every "
                f"{args.target_every}; fast preset, patience 0", "log": args.log_dir.name,
        "cpu_s": round(time.process_time() - c0, 1), "rows": rows}, indent=0) + "\n")


if __name__ == "__main__":
    main()
