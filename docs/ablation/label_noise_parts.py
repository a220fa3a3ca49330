"""What each part of the synthetic label noise costs warp mode (docs/reconstruction.md, label noise).

Re-labels the `easy` log of each seed of a `nuav2 bench ablation --work-dir WORK` run with one part of
the label noise at a time (nuav2.synth.labels.LabelNoiseParts; the images and LiDAR of `easy` and
`+label_noise` are the same files), converts each in warp mode into the nuScenes rig at 1/8 as the
ablation does, and scores it against the world's exact render. Usage (from the repository root):

    python docs/ablation/label_noise_parts.py --work-dir WORK --seeds 0,1 --out parts.json
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.feather as feather

from converters.av2 import read_log
from nuav2.convert import ConvertOptions, convert_av2
from nuav2.evaluate.against_world import key_camera_images, log_offsets, score_against_world
from nuav2.geometry import T_from_quat_trans, T_to_quat_trans
from nuav2.synth import load_world
from nuav2.synth.labels import LabelNoiseParts, label_errors

POSE = ["qw", "qx", "qy", "qz", "tx_m", "ty_m", "tz_m"]
SIZE = ["length_m", "width_m", "height_m"]
NONE = LabelNoiseParts(False, False, False, False)
VARIANTS = {
    "exact": NONE,
    "all": LabelNoiseParts(),
    "track_offset": LabelNoiseParts(track_offset=True, size=False, frame_jitter=False, missed=False),
    "size": LabelNoiseParts(track_offset=False, size=True, frame_jitter=False, missed=False),
    "frame_jitter": LabelNoiseParts(track_offset=False, size=False, frame_jitter=True, missed=False),
    "missed": LabelNoiseParts(track_offset=False, size=False, frame_jitter=False, missed=True),
}
REGIONS = ("whole", "ground", "objects", "nonrigid")


def relabel(src: Path, dst: Path, seed: int, parts: LabelNoiseParts) -> None:
    """A copy of log ``src`` (files linked) whose cuboids carry the chosen parts of the label noise."""
    dst.mkdir(parents=True)
    for f in src.iterdir():
        if f.name != "annotations.feather":
            os.symlink(f.resolve(), dst / f.name)
    table = feather.read_table(src / "annotations.feather")
    ann = table.to_pandas()
    out = []
    for ts, g in ann.groupby("timestamp_ns", sort=True):
        ego_T_box = T_from_quat_trans(g[POSE[:4]].to_numpy(), g[POSE[4:]].to_numpy())
        ego_T_label, size, kept = label_errors(seed, list(g.track_uuid), int(ts), ego_T_box,
                                               g[SIZE].to_numpy(), g.num_interior_pts.to_numpy(), parts)
        q, t = T_to_quat_trans(ego_T_label)
        g = g.copy()
        g[POSE[:4]], g[POSE[4:]], g[SIZE] = q, t, size
        out.append(g[kept])
    merged = pa.Table.from_pandas(pd.concat(out), schema=table.schema, preserve_index=False)
    feather.write_feather(merged, dst / "annotations.feather")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work-dir", type=Path, required=True, help="a `nuav2 bench ablation --work-dir` folder")
    ap.add_argument("--seeds", default="0,1")
    ap.add_argument("--scratch", type=Path, default=Path("label_noise_parts"),
                    help="where the relabelled logs and their conversions go")
    ap.add_argument("--variants", default=",".join(VARIANTS),
                    help="comma-separated subset of: " + ", ".join(VARIANTS) + " (exact is always run)")
    ap.add_argument("--out", type=Path, default=None, help="JSON of every score")
    args = ap.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    names = ["exact"] + [v for v in args.variants.split(",") if v and v != "exact"]
    unknown = sorted(set(names) - set(VARIANTS))
    if unknown:
        ap.error(f"--variants: unknown {', '.join(unknown)} (choose from {', '.join(VARIANTS)})")
    scores: dict[str, dict[str, dict[str, float]]] = {}
    for seed in seeds:
        src = next((args.work_dir / f"seed{seed}" / "easy" / "av2" / "train").iterdir())
        world = load_world(src)
        vector_map = read_log(src).vector_map
        for name in names:
            parts = VARIANTS[name]
            log_dir = args.scratch / "logs" / f"seed{seed}" / name / src.name
            shutil.rmtree(log_dir.parent, ignore_errors=True)
            relabel(src, log_dir, seed, parts)
            out = args.scratch / "out" / f"seed{seed}" / name
            shutil.rmtree(out, ignore_errors=True)
            opts = ConvertOptions(mode="warp", rig="nuscenes", scale=0.125, show_progress=False)
            convert_av2(log_dir, out, opts)
            images = key_camera_images(out, opts.version, log_offsets(out, opts.version))
            psnr = score_against_world(images, world, vector_map=vector_map).summary()["psnr_db"]
            scores.setdefault(name, {})[str(seed)] = {r: round(float(psnr[r]), 4) for r in REGIONS}
            print(f"seed {seed} {name}: " + ", ".join(f"{r} {psnr[r]:.3f}" for r in REGIONS), flush=True)
    print("\n| labels | " + " | ".join(f"{r} dB lost (mean over seeds)" for r in REGIONS) + " |")
    print("|---|" + "---|" * len(REGIONS))
    for name in names:
        lost = [np.mean([scores["exact"][str(s)][r] - scores[name][str(s)][r] for s in seeds])
                for r in REGIONS]
        print(f"| {name} | " + " | ".join(f"{v:.3f}" for v in lost) + " |")
    if args.out:
        args.out.write_text(json.dumps({"seeds": seeds, "psnr_db": scores}, indent=1))


if __name__ == "__main__":
    main()
