"""Other strengths of the footprint widening (nuav2.splat.footprint), scored at 1600 x 900 against the
world's exact render: none, half, the default (full), twice, and the full amount with Mip-Splatting's
opacity compensation (opacity x sqrt(det S / det S')). Prints one JSON line per log:

    nuav2 synth --seed 0 --seconds 2 LOGS            # and --preset hard
    python docs/ablation/footprint_strengths.py LOGS/train/<log_id> ...
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

import nuav2.splat as splat_package
import nuav2.splat.scene_model as scene_model
from converters.av2 import read_log
from nuav2.bench.recon import eval_times
from nuav2.evaluate.against_world import truth_view, world_region_masks
from nuav2.evaluate.image_metrics import psnr
from nuav2.recon import ReconConfig, reconstruct
from nuav2.rig import load_rig
from nuav2.splat.render_target import target_city_T_cams
from nuav2.synth import load_world

# name: (fraction of the extra 2D variance, opacity compensated)
VARIANTS = {"as_trained": (0.0, False), "half": (0.5, False), "widened": (1.0, False),
            "twice": (2.0, False), "widened_compensated": (1.0, True)}
MODE = {"fraction": 1.0, "compensate": False, "log_scales": None}
WIDEN, RASTERIZE = scene_model.widen_to_training_footprint, splat_package.rasterize


def widen(log_scales, means, scene_T_cam, target_f, train_f):
    """The default widening with its extra variance scaled by MODE["fraction"]."""
    MODE["log_scales"] = log_scales
    if MODE["fraction"] == 0 or train_f is None or target_f <= train_f:
        return log_scales
    f_eff = 1.0 / np.sqrt((1 - MODE["fraction"]) / target_f**2 + MODE["fraction"] / train_f**2)
    return WIDEN(log_scales, means, scene_T_cam, target_f, f_eff)


def rasterize(means, quats, log_scales, opacity_logits, *args, **kw):
    """The rasterizer, with opacity scaled by prod(s) / prod(s') when MODE["compensate"]."""
    if MODE["compensate"] and log_scales is not MODE["log_scales"]:
        o = torch.sigmoid(opacity_logits) * torch.exp((MODE["log_scales"] - log_scales).sum(-1))
        opacity_logits = torch.logit(o.clamp(1e-6, 1 - 1e-6))
    return RASTERIZE(means, quats, log_scales, opacity_logits, *args, **kw)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("log_dirs", type=Path, nargs="+")
    ap.add_argument("--times", type=int, default=3)
    args = ap.parse_args()
    scene_model.widen_to_training_footprint, splat_package.rasterize = widen, rasterize
    rig = load_rig("nuscenes", scale=1.0)
    for log_dir in args.log_dirs:
        scene, world = read_log(log_dir), load_world(log_dir)
        splat = reconstruct(scene, ReconConfig.fast(), progress=False)
        acc = {name: {r: [] for r in ("whole", "ground", "objects", "sky")} for name in VARIANTS}
        for t in eval_times(scene, args.times):
            poses = target_city_T_cams(scene, rig, int(t))
            for cam in rig.cameras:
                truth, labels = truth_view(world, cam, poses[cam.channel], int(t))
                masks, ref = world_region_masks(labels), truth.astype(np.float32) / 255
                for name, (fraction, compensate) in VARIANTS.items():
                    MODE["fraction"], MODE["compensate"] = fraction, compensate
                    with torch.no_grad():
                        img = splat.render(cam, poses[cam.channel], int(t)).rgb.clamp(0, 1).numpy()
                    for region, values in acc[name].items():
                        if masks[region].any():
                            values.append(psnr(img, ref, mask=masks[region]))
        print(json.dumps({"log": log_dir.name, **{n: {r: round(float(np.mean(v)), 3) for r, v in a.items()}
                                                 for n, a in acc.items()}}), flush=True)


if __name__ == "__main__":
    main()
