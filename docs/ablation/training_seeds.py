"""How much of a render-mode row's score is the reconstruction's own random seed (docs/reconstruction.md).

The ablation (`nuav2 bench ablation`) trains each row's reconstruction once, with seed 0. This script
converts the same synthetic logs in render mode (`fast`, nuScenes rig at 1/8, as the ablation does) with
several reconstruction seeds (`ReconConfig.seed`: the view order, densification draws and seed
thinning), scores every conversion against the world's exact render, and reports each row's cost
against `easy` paired by world seed and training seed, with its spread. Usage (from the repository root):

    python docs/ablation/training_seeds.py --rows +label_noise --seeds 0,1 --recon-seeds 0,1,2 \
        --work-dir WORK --out seeds.json

(WORK keeps the logs, conversions and scores; a rerun reuses the logs and the scored conversions.)
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
from dataclasses import replace
from pathlib import Path

import nuav2.recon as recon
from converters.av2 import read_log
from nuav2.bench.ablation import ROW_EASY, AblationOptions, ablation_rows
from nuav2.convert import ConvertOptions, convert_av2
from nuav2.evaluate.against_world import key_camera_images, log_offsets, score_against_world
from nuav2.synth import generate_log, load_world
from nuav2.synth.camera_effects import log_reference_gain

REGIONS = ("whole", "ground", "objects", "sky", "nonrigid")


OPTIONS = ConvertOptions(mode="render", rig="nuscenes", scale=0.125, recon_preset="fast", show_progress=False)


def convert_with_seed(log_dir: Path, out: Path, recon_seed: int) -> None:
    """Render-mode conversion of one log, the `fast` reconstruction trained with seed ``recon_seed``."""
    fast = recon.ReconConfig.fast
    recon.ReconConfig.fast = staticmethod(lambda: replace(fast(), seed=recon_seed))
    try:
        shutil.rmtree(out, ignore_errors=True)
        report = convert_av2(log_dir, out, OPTIONS)
        if report.failed:
            raise SystemExit(f"{log_dir}: conversion failed: {report.failed}")
    finally:
        recon.ReconConfig.fast = fast


def score(dataroot: Path, world, vector_map, reference_gain) -> dict:
    images = key_camera_images(dataroot, OPTIONS.version, log_offsets(dataroot, OPTIONS.version))
    s = score_against_world(images, world, vector_map=vector_map, reference_gain=reference_gain).summary()
    return {r: s["psnr_db"][r] for r in REGIONS if s["psnr_db"].get(r) is not None}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rows", default="+label_noise", help="ablation rows besides easy, comma-separated")
    ap.add_argument("--seeds", default="0,1", help="world seeds")
    ap.add_argument("--recon-seeds", default="0,1,2", help="reconstruction seeds")
    ap.add_argument("--work-dir", type=Path, required=True)
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args()
    configs = dict(ablation_rows(AblationOptions()))
    rows = [ROW_EASY, *[r for r in a.rows.split(",") if r and r != ROW_EASY]]
    unknown = [r for r in rows if r not in configs]
    if unknown:
        raise SystemExit(f"--rows: unknown rows {unknown}; known: {list(configs)}")
    seeds = [int(s) for s in a.seeds.split(",")]
    recon_seeds = [int(s) for s in a.recon_seeds.split(",")]
    runs = []
    for seed in seeds:
        for row in rows:
            logs = a.work_dir / "logs" / f"{row}_{seed}"
            if not (logs / "train").is_dir():
                generate_log(logs, seed=seed, config=configs[row])
            log_dir = next((logs / "train").iterdir())
            truth = None  # the log's world, map and exposure: read once, and only if a run needs scoring
            for rs in recon_seeds:
                out = a.work_dir / "render" / f"{row}_{seed}_{rs}"
                done = a.work_dir / "render" / f"{row}_{seed}_{rs}.json"  # a finished run is reused
                if not done.is_file():
                    convert_with_seed(log_dir, out, rs)
                    truth = truth or (load_world(log_dir), read_log(log_dir).vector_map,
                                      log_reference_gain(log_dir))
                    done.write_text(json.dumps(score(out, *truth)))
                psnr = json.loads(done.read_text())
                runs.append({"row": row, "seed": seed, "recon_seed": rs, "psnr_db": psnr})
                print(json.dumps(runs[-1]), flush=True)
    by = {(r["row"], r["seed"], r["recon_seed"]): r["psnr_db"] for r in runs}
    summary = {}
    for row in rows[1:]:
        def cost(s: int, k: int, row: str = row) -> float:
            return by[(ROW_EASY, s, k)]["whole"] - by[(row, s, k)]["whole"]

        costs = [cost(s, k) for s in seeds for k in recon_seeds]
        sd = statistics.stdev(costs) if len(costs) > 1 else None
        summary[row] = {"cost_db_mean": round(statistics.mean(costs), 3),
                        "cost_db_sd": None if sd is None else round(sd, 3),
                        "cost_db_se": None if sd is None else round(sd / len(costs) ** 0.5, 3),
                        "cost_db_first_recon_seed_only": round(statistics.mean(
                            [cost(s, recon_seeds[0]) for s in seeds]), 3),
                        "pairs": len(costs)}
    spread = {f"{row}/{s}": round(max(by[(row, s, k)]["whole"] for k in recon_seeds)
                                  - min(by[(row, s, k)]["whole"] for k in recon_seeds), 3)
              for row in rows for s in seeds}
    out = {"command": "python docs/ablation/training_seeds.py " + " ".join(
               f"--{k.replace('_', '-')} {v}" for k, v in [("rows", a.rows), ("seeds", a.seeds),
                                                          ("recon_seeds", a.recon_seeds)]),
           "runs": runs, "cost_vs_easy": summary, "whole_psnr_range_over_recon_seeds": spread}
    a.out.write_text(json.dumps(out, indent=1) + "\n")
    print(json.dumps({"cost_vs_easy": summary, "whole_psnr_range_over_recon_seeds": spread}, indent=1))


if __name__ == "__main__":
    main()
