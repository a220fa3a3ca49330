"""The empty road and the busy junction at each other's Gaussian budget (`default` preset).

The scene budget gives the empty straight road fewer Gaussians than the busy junction; this checks
that the difference costs the empty road nothing and that the junction needs its extra Gaussians:
each scene is reconstructed at its own scene budget and at the other scene's (``BudgetConfig``
min = max = that number), the four runs interleaved in one process (own budgets first, since the
crossed runs need them), each scored in the nuScenes rig at 1/8 against the world's exact render and
on held-out source images (every 5th per camera). One JSON line per run:

    python docs/ablation/budget_crossover.py WORKDIR [--recon-seed S] >> docs/ablation/budget_crossover.jsonl

WORKDIR keeps the two generated logs (``bench recon --scene empty,busy``'s worlds, `easy` seed 0), so a
rerun reuses them.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

from converters.av2 import read_log
from nuav2.bench.recon import SCENES, heldout_psnr, target_rig_scores
from nuav2.bench.timing import Stopwatch
from nuav2.recon import ReconConfig, reconstruct
from nuav2.synth import SynthConfig, generate_log, load_world


def scene_log(work: Path, name: str, preset: str, seed: int) -> Path:
    """The scene's synthetic log under ``work/name`` (generated once)."""
    root = work / name
    found = sorted((root / "train").glob("*")) if root.exists() else []
    if found:
        return found[0]
    return generate_log(root, seed=seed, config=SynthConfig.for_preset(preset, **SCENES[name]))


def run(log: Path, scene_name: str, budget: int | None, times: int, recon_seed: int) -> dict:
    """One `default` reconstruction at ``budget`` Gaussians (None: the scene's own budget), scored."""
    scene, world = read_log(log), load_world(log)
    cfg = replace(ReconConfig.default(), holdout_every=5, seed=recon_seed)
    if budget is not None:
        fixed = replace(cfg.init.budget, min_budget=budget, max_budget=budget)
        cfg = replace(cfg, init=replace(cfg.init, budget=fixed))
    sw = Stopwatch()
    with sw:
        splat = reconstruct(scene, cfg, progress=False)
    train, init = splat.info["train"], splat.info.get("init_stats") or {}
    target = target_rig_scores(splat, scene, world, n_times=times)
    held = heldout_psnr(splat, scene)
    return {"scene": scene_name, "log": scene.log_id, "recon_seed": recon_seed,
            "budget": "own" if budget is None else budget,
            "scene_budget": init.get("gaussian_budget"), "gaussians": splat.num_gaussians(),
            "steps": train["steps"], "stop_reason": train["stop_reason"], "cooldown": train.get("cooldown"),
            "recon_wall_s": round(sw.wall_s[0], 1), "recon_cpu_s": round(sw.cpu_s[0], 1),
            "load_1min": sw.load[0],
            "psnr_db": round(target["psnr_db"], 3), "ssim": round(target["ssim"], 4),
            **{f"psnr_{k}_db": round(v, 3) for k, v in target["regions"]["psnr_db"].items() if v is not None},
            "heldout_psnr_db": None if held is None else round(held["psnr_db"], 3)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("work", type=Path, help="folder for the two synthetic logs (reused when present)")
    ap.add_argument("--preset", default="easy", help="synthetic realism preset")
    ap.add_argument("--seed", type=int, default=0, help="synthetic world seed")
    ap.add_argument("--recon-seed", type=int, default=0, help="the reconstruction's seed (ReconConfig.seed)")
    ap.add_argument("--times", type=int, default=6, help="sample times scored in the nuScenes rig")
    args = ap.parse_args()
    logs = {name: scene_log(args.work, name, args.preset, args.seed) for name in ("empty", "busy")}
    own: dict[str, int] = {}
    for name in ("empty", "busy"):
        row = run(logs[name], name, None, args.times, args.recon_seed)
        own[name] = int(row["scene_budget"])
        print(json.dumps(row), flush=True)
    for name, other in (("empty", "busy"), ("busy", "empty")):
        print(json.dumps(run(logs[name], name, own[other], args.times, args.recon_seed)), flush=True)


if __name__ == "__main__":
    main()
