"""One training run of the mapping model: AdamW, warmup + cosine, deep supervision, checkpoints.

A run lives in its own directory. ``checkpoint.pt`` (model, optimiser, step, learning curve) is
written atomically every ``checkpoint_every`` steps, so a killed run resumes where it stopped;
the batch order is a pure function of (seed, step) — seeded permutations per epoch — so a
resumed run sees the same batches as an uninterrupted one. When the run ends, ``model.pt`` and
``run.json`` (configs, curve, timing) appear, and a rerun with the same configuration returns
them without training.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import os
import time
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch

from nuav2.atomic import atomic_file, atomic_write_json
from nuav2.mapping.augment import bev_flip, photometric, random_rotation
from nuav2.mapping.config import MapModelConfig, TrainConfig, fingerprint
from nuav2.mapping.data import MapTensors
from nuav2.mapping.losses import dense_loss, depth_loss, set_loss
from nuav2.mapping.model import ARCHITECTURE, MapModel, load_weights

log = logging.getLogger(__name__)

CHECKPOINT = "checkpoint.pt"
MODEL = "model.pt"
RUN_JSON = "run.json"

# evaluator(model) -> {"mAP": float, ...}; called on the learning-curve steps.
Evaluator = Callable[[MapModel], dict]


def batch_indices(n: int, batch_size: int, seed: int, step: int) -> list[int]:
    """Samples of ``step``: consecutive slots of seeded per-epoch permutations (deterministic per step)."""
    out = []
    for pos in range(step * batch_size, (step + 1) * batch_size):
        epoch, k = divmod(pos, n)
        out.append(int(np.random.default_rng([seed, epoch]).permutation(n)[k]))
    return out


def learning_rate(cfg: TrainConfig, step: int) -> float:
    if step < cfg.warmup_steps:
        return cfg.lr * (step + 1) / cfg.warmup_steps
    t = (step - cfg.warmup_steps) / max(1, cfg.steps - cfg.warmup_steps)
    return cfg.lr * (0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * min(1.0, t))))


def run_fingerprint(
    model_cfg: MapModelConfig, train_cfg: TrainConfig, data: MapTensors, init_weights: Path | None
) -> str:
    """Everything a run's result depends on; the initial weights by content (a retrained
    pretraining run invalidates its fine-tuning runs)."""
    init = hashlib.sha256(Path(init_weights).read_bytes()).hexdigest()[:16] if init_weights else None
    return fingerprint(model_cfg, train_cfg, data.meta, len(data), init, {"architecture": ARCHITECTURE})


def _save_atomic(obj, path: Path) -> None:
    """torch.save through a temp file: a killed save leaves neither a torn checkpoint nor a temp file."""
    with atomic_file(path) as f:
        torch.save(obj, f)


def load_model(run_dir: str | Path) -> MapModel:
    """The trained model of a finished run directory."""
    from nuav2.mapping.config import model_config_from_dict

    run_dir = Path(run_dir)
    info = json.loads((run_dir / RUN_JSON).read_text())
    model = MapModel(model_config_from_dict(info["model_config"]))
    load_weights(model, torch.load(run_dir / MODEL, weights_only=True), run_dir / MODEL)
    return model.eval()


def _loss(model: MapModel, batch: dict, train_cfg: TrainConfig) -> dict[str, torch.Tensor]:
    cfg = model.cfg
    one2many = cfg.one2many_queries > 0
    out = model(batch["img"], batch["lidar2img"], batch["img_hw"], one2many=one2many)
    w = train_cfg.loss
    n = cfg.num_queries
    layers = out["layers"]
    losses = set_loss(
        [(c[:, :n], p[:, :n]) for c, p in layers], batch["gt_labels"], batch["gt_shifts"], cfg, w
    )
    if one2many:  # MapTRv2 hybrid matching: the extra queries learn from the GT repeated k times
        k = cfg.one2many_k
        many = set_loss(
            [(c[:, n:], p[:, n:]) for c, p in layers],
            [g.repeat(k) for g in batch["gt_labels"]],
            [s.repeat(k, 1, 1, 1) for s in batch["gt_shifts"]],
            cfg,
            w,
        )
        for key, v in many.items():
            losses[f"{key}_one2many"] = w.one2many_weight * v
    losses["bev_seg"] = w.bev_seg_weight * dense_loss(out["bev_seg"], batch["bev_target"])
    h, w_ = out["pv_seg"].shape[-2:]
    s = cfg.feat_stride
    ys = torch.arange(h).view(1, 1, h, 1) * s + (s - 1) / 2
    xs = torch.arange(w_).view(1, 1, 1, w_) * s + (s - 1) / 2
    inside = ((ys < batch["img_hw"][..., 0, None, None]) & (xs < batch["img_hw"][..., 1, None, None])).float()
    losses["pv_seg"] = w.pv_seg_weight * dense_loss(out["pv_seg"], batch["pv_target"], inside.unsqueeze(2))
    losses["depth"] = w.depth_weight * depth_loss(out["depth"], batch["depth_target"])
    return losses


def train(
    model_cfg: MapModelConfig,
    train_cfg: TrainConfig,
    data: MapTensors,
    run_dir: str | Path,
    *,
    init_weights: str | Path | None = None,
    evaluator: Evaluator | None = None,
    progress: bool | None = None,  # False: no progress display; else a bar on a terminal, log lines elsewhere
) -> dict:
    """Train (or resume, or reuse) the run in ``run_dir``; returns its ``run.json`` record.

    ``init_weights``: a finished run's ``model.pt`` to start from (fine-tuning), else from scratch.
    """
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    key = run_fingerprint(model_cfg, train_cfg, data, init_weights)
    done = run_dir / RUN_JSON
    if done.is_file() and (run_dir / MODEL).is_file():
        info = json.loads(done.read_text())
        if info.get("fingerprint") == key:
            return info
    if len(data) == 0:
        raise ValueError(f"{run_dir}: no training keyframes")
    torch.set_num_threads(train_cfg.threads)
    torch.manual_seed(train_cfg.seed)
    model = MapModel(model_cfg)
    if init_weights:
        load_weights(model, torch.load(init_weights, weights_only=True), init_weights)
    opt = torch.optim.AdamW(model.parameters(), lr=train_cfg.lr, weight_decay=train_cfg.weight_decay)
    step, curve, losses = 0, [], []
    elapsed = {"wall_s": 0.0, "cpu_s": 0.0, "eval_wall_s": 0.0}
    loss_every = max(1, train_cfg.steps // 50)
    ckpt = run_dir / CHECKPOINT
    if ckpt.is_file():
        state = torch.load(ckpt, weights_only=False)
        if state.get("fingerprint") == key:
            model.load_state_dict(state["model"])
            opt.load_state_dict(state["optim"])
            step, curve, losses, elapsed = state["step"], state["curve"], state["losses"], state["elapsed"]
            log.info("%s: resuming at step %d of %d", run_dir, step, train_cfg.steps)
    eval_steps = set(
        range(train_cfg.eval_every, train_cfg.steps, train_cfg.eval_every) if train_cfg.eval_every else []
    ) | {train_cfg.steps}
    from nuav2.progress import progress_bar

    bar = progress_bar(
        total=train_cfg.steps,
        initial=step,
        desc=f"train {run_dir.name}",
        unit="step",
        disable=progress is False,
    )
    model.train()
    try:
        while step < train_cfg.steps:
            t0, c0 = time.perf_counter(), time.process_time()
            for g in opt.param_groups:
                g["lr"] = learning_rate(train_cfg, step)
            index = batch_indices(len(data), train_cfg.batch_size, train_cfg.seed, step)
            batch = data.batch(index)
            gen = torch.Generator().manual_seed(train_cfg.seed * 1_000_003 + step)
            batch["img"] = photometric(batch["img"], gen)
            if train_cfg.bev_rotate and data.rotated:
                batch = random_rotation(batch, data, index, gen)
            if train_cfg.bev_flip:
                batch = bev_flip(batch, gen)
            terms = _loss(model, batch, train_cfg)
            total = sum(terms.values())
            if not torch.isfinite(total):
                raise FloatingPointError(f"{run_dir}: loss is {float(total)} at step {step} ({terms})")
            if step % loss_every == 0:
                losses.append(
                    {
                        "step": step,
                        "total": total.detach().item(),
                        **{k: v.detach().item() for k, v in terms.items()},
                    }
                )
            opt.zero_grad(set_to_none=True)
            total.backward()
            torch.nn.utils.clip_grad_norm_(model.parameters(), train_cfg.grad_clip)
            opt.step()
            step += 1
            elapsed["wall_s"] += time.perf_counter() - t0
            elapsed["cpu_s"] += time.process_time() - c0
            bar.update()
            shown = {"loss": f"{total.detach().item():.3f}"}
            if curve:
                shown["mAP"] = f"{curve[-1]['mAP']:.3f}"
            bar.set_postfix(**shown)
            if step in eval_steps and evaluator is not None:
                t1 = time.perf_counter()
                curve.append({"step": step, **evaluator(model)})
                # the evaluator's numba kernels (OpenMP) reset torch's thread count to the machine's;
                # left so, a 1-thread run in a busy machine ran 10x slower after its first curve point
                torch.set_num_threads(train_cfg.threads)
                elapsed["eval_wall_s"] += time.perf_counter() - t1
            if (
                train_cfg.checkpoint_every and step % train_cfg.checkpoint_every == 0
            ) or step == train_cfg.steps:
                _save_atomic(
                    {
                        "fingerprint": key,
                        "model": model.state_dict(),
                        "optim": opt.state_dict(),
                        "step": step,
                        "curve": curve,
                        "losses": losses,
                        "elapsed": elapsed,
                    },
                    ckpt,
                )
    finally:
        bar.close()
    _save_atomic(model.state_dict(), run_dir / MODEL)
    info = {
        "fingerprint": key,
        "model_config": asdict(model_cfg),
        "train_config": asdict(train_cfg),
        "data": {**data.meta, "keyframes": len(data)},
        "init_weights": str(init_weights) if init_weights else None,
        "steps": step,
        "curve": curve,
        "losses": losses,
        "elapsed": elapsed,
        "load_avg": list(os.getloadavg()),
    }
    atomic_write_json(done, info, indent=1)
    return info
