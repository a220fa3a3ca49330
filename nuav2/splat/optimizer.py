"""The training's Adam optimizer: one named group per (Gaussian set, parameter), the sky and the
box-pose corrections, their base learning rates, and a step over only the groups with gradients.

Group order and names are fixed so that a checkpoint's optimizer state maps back onto the groups
of a resumed run; densification swaps a grown or pruned tensor into its group (nuav2.splat.densify).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch
from torch.autograd.graph import increment_version

from nuav2.splat.scene_model import GaussianSet, SplatScene

if TYPE_CHECKING:
    from nuav2.splat.train import TrainConfig


def named_sets(splat: SplatScene) -> dict[str, GaussianSet]:
    out = {"background": splat.background}
    for o in splat.objects:
        out[f"obj:{o.track.key}"] = o.gaussians
    return out


def store_sets(splat: SplatScene, sets: dict[str, GaussianSet]) -> None:
    splat.background = sets["background"]
    for o in splat.objects:
        o.gaussians = sets[f"obj:{o.track.key}"]


def base_lr(group_name: str, cfg: TrainConfig, extent: float) -> float:
    """Initial learning rate of an optimizer group named ``<set>/<param>`` or ``sky``."""
    if group_name == "sky":
        return cfg.lr_sky
    if group_name.startswith("pose:"):
        return cfg.lr_pose
    lrs = {"means": cfg.lr_means * extent, "quats": cfg.lr_quats, "log_scales": cfg.lr_scales,
           "opacity_logits": cfg.lr_opacity, "sh": cfg.lr_sh_dc}
    return lrs[group_name.rsplit("/", 1)[1]]


def build_optimizer(splat: SplatScene, cfg: TrainConfig, extent: float) -> torch.optim.Adam:
    """One Adam param group per (set, parameter) plus the sky, in a fixed order (checkpointable)."""
    groups = []
    for name, g in named_sets(splat).items():
        g.requires_grad_(True)
        for p in ("means", "quats", "log_scales", "opacity_logits", "sh"):
            groups.append({"params": [getattr(g, p)], "lr": base_lr(f"{name}/{p}", cfg, extent),
                           "name": f"{name}/{p}"})
    splat.sky.texture.requires_grad_(True)
    groups.append({"params": [splat.sky.texture], "lr": cfg.lr_sky, "name": "sky"})
    for o in splat.objects:
        if o.track.pose_delta is not None:
            o.track.pose_delta.requires_grad_(True)
            groups.append({"params": [o.track.pose_delta], "lr": cfg.lr_pose,
                           "name": f"pose:{o.track.key}"})
    return torch.optim.Adam(groups, lr=1e-3, eps=1e-15, fused=True)


def step_groups_with_grads(optimizer: torch.optim.Optimizer) -> None:
    """One optimizer step over the groups that have a gradient, then their gradients cleared.

    A 15 s log has ~460 groups (five per moving object) and a step gives ~30 a gradient (the
    background, the sky, the present objects): torch would skip the others one by one, which costs
    more than the fused update of those. Same update as ``optimizer.step()``: a group without
    gradients is left alone either way. Non-finite gradient entries are zeroed first (one bad pixel
    must not poison Adam's moments)."""
    every = optimizer.param_groups
    with_grads = [g for g in every if any(p.grad is not None for p in g["params"])]
    for g in with_grads:
        for p in g["params"]:
            if p.grad is not None:
                torch.nan_to_num_(p.grad, nan=0.0, posinf=0.0, neginf=0.0)
    optimizer.param_groups = with_grads
    try:
        optimizer.step()
    finally:
        optimizer.param_groups = every
    stepped = [p for g in with_grads for p in g["params"] if p.grad is not None]
    # fused Adam writes in place without bumping the version counter, which caches keyed on it
    # (GaussianSet.bounding_radius, for the view culling) rely on
    increment_version(stepped)
    for p in stepped:
        p.grad = None
