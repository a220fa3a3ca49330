"""Where render mode's ground on `hard` loses to `easy` (docs/reconstruction.md, "Where hard's ground goes").

The ablation adds each realism factor to `easy` alone; this takes each one *out* of `hard` instead
(`SynthConfig.for_preset("hard", <factor>=False)`, and `camera_noise=False`: the exposure factor's gains
without its sensor noise), converts each 2 s log in render mode into the nuScenes rig at 1/8 as
`nuav2 bench ablation` does (same code path: `nuav2.bench.ablation.run_row`), and prints one JSON line per
log with the raw and ref. PSNR (the log's true mean exposure taken out) of the whole image and the ground.
Then one summary line per row: mean over the seeds, and the gain over `hard` whole. Usage (from the
repository root; about 45 s per log with `fast` on 2 cores):

    python docs/ablation/hard_leave_one_out.py --seeds 0,1 [--recon-preset default] > loo.jsonl
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np

from nuav2.bench.ablation import AblationOptions, run_row
from nuav2.synth import FACTORS, SynthConfig

ROWS = ("hard", *(f"-{f}" for f in FACTORS), "-camera_noise")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="0,1", help="world seeds, comma-separated")
    ap.add_argument("--rows", default=",".join(ROWS), help="hard, and -<factor> for hard without it")
    ap.add_argument("--recon-preset", default="fast", choices=("fast", "default"))
    args = ap.parse_args()
    opts = AblationOptions(modes=("render",), recon_preset=args.recon_preset)
    seeds = [int(s) for s in args.seeds.split(",")]
    rows = [r.strip() for r in args.rows.split(",") if r.strip()]
    got: dict[str, dict[int, dict]] = {}
    for seed in seeds:
        for row in rows:
            off = {} if row == "hard" else {row[1:]: False}
            cfg = SynthConfig.for_preset("hard", seconds=2.0, image_scale=0.125, **off)
            with tempfile.TemporaryDirectory() as work:
                rec, _ = run_row(seed, cfg, opts, Path(work))
            m = rec["modes"]["render"]
            line = {"row": row, "seed": seed, "layout": rec["layout"], "raw": m["psnr_db"],
                    "ref": m["psnr_ref_db"], "convert_cpu_s": m["convert"]["cpu_s"]}
            got.setdefault(row, {})[seed] = line
            print(json.dumps(line), flush=True)
    for row, by_seed in got.items():
        mean = {k: {r: round(float(np.mean([v[k][r] for v in by_seed.values()])), 2)
                    for r in ("whole", "ground")} for k in ("raw", "ref")}
        summary = {"summary": row, "seeds": sorted(by_seed), **mean}
        if "hard" in got and set(got["hard"]) >= set(by_seed):
            summary["ref_ground_gain_over_hard_db"] = round(float(np.mean(
                [v["ref"]["ground"] - got["hard"][s]["ref"]["ground"] for s, v in by_seed.items()])), 2)
        print(json.dumps(summary), flush=True)


if __name__ == "__main__":
    main()
