"""A very small synthetic log and reconstruction budget for the device tests (seconds per run on 2 cores).

0.5 s (5 sweeps), three front ring cameras at 1/16 resolution (128x97), one parked and two moving
cars, a few thousand seeds: enough for every part of a training step (objects with pose refinement,
SH degree 1, densification with splits, validation) to run, far too little to judge quality.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import torch

from converters.av2 import read_log
from nuav2.recon import ReconConfig
from nuav2.scene import SceneLog
from nuav2.splat.densify import DensifyConfig
from nuav2.splat.init import InitConfig
from nuav2.splat.scene_model import SplatScene
from nuav2.splat.train import TrainConfig
from nuav2.synth import SynthConfig, generate_log

TINY_LOG = SynthConfig(seconds=0.5, image_scale=1 / 16, lidar_azimuth_steps=256, n_parked=1, n_moving=2,
                       n_pedestrians=0, map_margin_m=25.0)
TINY_SEED = 3  # with this seed both moving cars move enough to become objects
TINY_INIT = InitConfig(max_background=3000, ground_spacing_m=0.8, ground_radius_m=10.0)
CHANNELS = ("ring_front_center", "ring_front_left", "ring_front_right")


def tiny_scene(folder: Path) -> SceneLog:
    """Generate the tiny log into ``folder`` and read it back."""
    return read_log(generate_log(folder, seed=TINY_SEED, config=TINY_LOG))


def tiny_train_config(iterations: int = 8, **kw) -> TrainConfig:
    """Densify every 3 steps (splits draw random offsets), pose refinement from step 2, validation every 4."""
    densify = DensifyConfig(start=3, every=3, stop=iterations, budget=20_000, reset_every=0)
    cfg = TrainConfig(iterations=iterations, pyramid=(0.5, 1.0), pyramid_until=(0.5,), densify=densify,
                      pose_start=2, eval_every=4, eval_views=2, patience=0)
    return replace(cfg, **kw)


def tiny_recon_config(iterations: int = 8, **kw) -> ReconConfig:
    cfg = ReconConfig(sh_degree=1, train_width_px=128, channels=CHANNELS, holdout_every=0, validation_every=5,
                      init=TINY_INIT, train=tiny_train_config(iterations))
    return replace(cfg, **kw)


def copy_scene(splat: SplatScene) -> SplatScene:
    """An independent copy (a trainer changes its scene in place), on the CPU."""
    return SplatScene.from_state(splat.state())


def scene_tensors(splat: SplatScene) -> dict[str, torch.Tensor]:
    """Every learned tensor of a scene by name (Gaussians of each set, sky, box corrections), on the CPU."""
    out = {f"background/{k}": v for k, v in splat.background.tensors().items()}
    for o in splat.objects:
        out.update({f"{o.track.key}/{k}": v for k, v in o.gaussians.tensors().items()})
        if o.track.pose_delta is not None:
            out[f"{o.track.key}/pose_delta"] = o.track.pose_delta
    out["sky"] = splat.sky.texture
    return {k: v.detach().cpu() for k, v in out.items()}
