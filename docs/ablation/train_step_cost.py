"""Cost of one training iteration of a saved synthetic log, at the coarse and the full resolution.

Seeds the log as ``reconstruct`` does (preset ``fast``), then runs the trainer from its first state
for ``--steps`` timed iterations at each pyramid level (after 15 untimed ones) and prints one JSON line:
wall and CPU (``time.process_time``, all threads) milliseconds per iteration, the sum of the losses
(equal sums mean the same training) and the Gaussian count. Works on any checkout since issue 13's
presets (``git worktree add DIR COMMIT``, then ``PYTHONPATH=DIR python docs/ablation/train_step_cost.py
LOG``); alternate the checkouts run by run on a quiet machine, and discard a fresh checkout's first
run (it compiles its kernels).
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import nuav2  # noqa: F401  (first: sets the OpenMP wait policy before torch loads, as the CLI does)
from converters.av2 import read_log
from nuav2.recon import ReconConfig, reconstruct
from nuav2.splat import train as train_module
from nuav2.splat.scene_model import SplatScene


class _Seeded(Exception):
    """Raised from the trainer's constructor once seeding is done: its arguments are all we need."""


def seeded_trainer_args(log_dir: Path) -> tuple:
    scene = read_log(log_dir)
    captured = {}
    original = train_module.Trainer.__init__

    def capture(self, splat, scene_, views, sky_masks, cfg, validation=()):
        captured.update(state=splat.state(), views=views, sky=sky_masks, cfg=cfg, validation=list(validation))
        raise _Seeded

    train_module.Trainer.__init__ = capture
    try:
        reconstruct(scene, ReconConfig.fast(), progress=False)
    except _Seeded:
        pass
    finally:
        train_module.Trainer.__init__ = original
    return scene, captured


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("log_dir", type=Path, help="a synthetic AV2 log folder (nuav2 synth)")
    ap.add_argument("--steps", type=int, default=100, help="timed iterations per level")
    args = ap.parse_args()
    scene, c = seeded_trainer_args(args.log_dir)
    cfg = c["cfg"]
    out: dict = {"log": args.log_dir.name[:8], "iterations_cap": cfg.iterations}
    for name, start in (("coarse", 10), ("full", int(0.6 * cfg.iterations))):
        trainer = train_module.Trainer(SplatScene.from_state(c["state"]), scene, c["views"], c["sky"], cfg,
                                       validation=c["validation"])
        trainer.step = start  # the pyramid level follows the step
        for _ in range(15):
            trainer.train_step()
        w0, c0 = time.perf_counter(), time.process_time()
        losses = [trainer.train_step()[0] for _ in range(args.steps)]
        out[name] = {"wall_ms": round(1000 * (time.perf_counter() - w0) / args.steps, 1),
                     "cpu_ms": round(1000 * (time.process_time() - c0) / args.steps, 1),
                     "loss_sum": round(sum(losses), 6), "gaussians": trainer.splat.num_gaussians()}
    out["load_1min"] = round(os.getloadavg()[0], 2)
    print(json.dumps(out), flush=True)


if __name__ == "__main__":
    main()
