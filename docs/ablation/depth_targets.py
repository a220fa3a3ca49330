"""Time the trainer's LiDAR depth targets for a log's training views (the `--preset`'s split), as the
trainer builds them, and hash them. Runs on this checkout and on older ones (one view at a time there),
so two checkouts give comparable JSON lines and the same hash:

    git worktree add /tmp/old COMMIT
    for wt in /tmp/old .; do PYTHONPATH=$wt python docs/ablation/depth_targets.py LOGS/train/<log_id>; done
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import time
from pathlib import Path

import numpy as np
import torch

import nuav2.splat.train_views as train_views
from converters.av2 import read_log
from nuav2.geometry import T_inverse
from nuav2.recon import ReconConfig, default_channels, split_views
from nuav2.splat.views import source_views


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("log_dir", type=Path)
    ap.add_argument("--preset", default="fast", choices=("fast", "default"))
    args = ap.parse_args()
    cfg = ReconConfig.preset(args.preset)
    torch.set_num_threads(cfg.threads)
    scene = read_log(args.log_dir)
    views = source_views(scene, cfg.scale_for(scene), channels=default_channels(scene))
    used, _ = split_views(views, cfg.frame_stride, keep_every=True)
    train, _ = split_views(used, cfg.holdout_every)
    scene_T_city = T_inverse(scene.city_T_ego_at(int(scene.sweep_timestamps_ns[0])))
    c, w = time.process_time(), time.perf_counter()
    if hasattr(train_views, "lidar_depth_by_view"):
        out = train_views.lidar_depth_by_view(scene, train, scene_T_city, threads=cfg.threads)
    else:  # before: one view at a time, keeping the last sweep read
        cache: dict = {}
        out = [train_views.lidar_depth_samples(scene, v, scene_T_city, sweep_cache=cache) for v in train]
    wall, cpu = time.perf_counter() - w, time.process_time() - c
    digest = hashlib.sha256(b"".join(np.ascontiguousarray(u).tobytes() for u in out)).hexdigest()[:12]
    print(json.dumps({"views": len(train), "wall_s": round(wall, 2), "cpu_s": round(cpu, 2), "hash": digest,
                      "load_1min": round(os.getloadavg()[0], 2)}))


if __name__ == "__main__":
    main()
