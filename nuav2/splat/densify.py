"""Adaptive density control under a Gaussian budget (3DGS clone/split/prune as a strategy object).

The trainer calls :meth:`DensifyStrategy.accumulate` after each backward pass with the
screen-space gradients of every rasterized Gaussian, and :meth:`DensifyStrategy.step` once
per iteration. Every ``every`` iterations inside ``[start, stop)``:

- Gaussians whose mean view-space gradient (NDC units, as gsplat) exceeds the threshold grow:
  small ones are cloned, large ones (max scale > ``split_scale_frac`` x extent) are split in two
  samples of themselves shrunk by 1.6;
- when growth would pass the budget, only the highest-gradient candidates (across all sets)
  grow, so the total never exceeds ``budget``;
- Gaussians with opacity < ``prune_opacity``, world scale > ``prune_scale_frac`` x extent, or
  (objects) a mean far outside their box are removed.

Every ``reset_every`` iterations opacities are clamped down to ``reset_opacity`` (written so
that it actually fires; gsplat 1.5.3's precedence bug never resets). Optimizer state follows
the parameters: surviving rows keep their Adam moments, new rows start at zero.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import torch

from nuav2.splat.scene_model import PARAM_NAMES, GaussianSet, inverse_sigmoid


@dataclass(frozen=True)
class DensifyConfig:
    start: int = 100
    stop: int = 1600
    every: int = 100
    grad_threshold: float = 2e-4  # mean |d loss / d means2d| in NDC units
    split_scale_frac: float = 0.01  # of the scene extent: larger Gaussians split, smaller clone
    prune_opacity: float = 0.005
    prune_scale_frac: float = 0.1  # of the scene extent
    object_box_margin: float = 1.5  # object Gaussians beyond this multiple of the half box size go
    reset_every: int = 0  # 0: never (a reset costs more than it gains in a few thousand iterations)
    reset_opacity: float = 0.01
    budget: int = 100_000
    min_views: int = 1  # a Gaussian needs this many visible renders since the last step to grow


@dataclass
class _Stats:
    grad: torch.Tensor  # (N,) summed NDC gradient norms
    count: torch.Tensor  # (N,) renders in which the Gaussian was visible


@dataclass
class DensifyStrategy:
    """Clone/split/prune/reset for a dict of named Gaussian sets sharing one budget."""

    cfg: DensifyConfig
    extent: float
    stats: dict[str, _Stats] = field(default_factory=dict)
    history: list[dict] = field(default_factory=list)
    stopped_at: int | None = None  # densification ended here, before ``cfg.stop`` (validation plateau)

    @property
    def stop(self) -> int:
        return self.cfg.stop if self.stopped_at is None else min(self.cfg.stop, self.stopped_at)

    def active(self, step: int) -> bool:
        return step < self.stop

    def _stats_for(self, name: str, n: int, device: torch.device) -> _Stats:
        st = self.stats.get(name)
        if st is None or len(st.grad) != n:
            st = _Stats(torch.zeros(n, device=device), torch.zeros(n, device=device))
            self.stats[name] = st
        return st

    def accumulate(self, name: str, grad_px: torch.Tensor, visible: torch.Tensor, width: int,
                   height: int, rows: torch.Tensor | None = None, n: int | None = None) -> None:
        """Add one render's screen-space gradients (M, 2) pixel units of set ``name``: of all its
        Gaussians, or of its ``rows`` (distinct) in a set of ``n`` (a render reaches a third of them)."""
        g = grad_px.detach() * torch.tensor([width / 2.0, height / 2.0], dtype=grad_px.dtype,
                                            device=grad_px.device)
        st = self._stats_for(name, len(g) if rows is None else int(n), g.device)
        norm = torch.nan_to_num(g.norm(dim=-1), nan=0.0, posinf=0.0)
        norm = torch.where(visible, norm, torch.zeros_like(norm))
        if rows is None:
            st.grad += norm
            st.count += visible.float()
        else:
            st.grad.index_add_(0, rows, norm)
            st.count.index_add_(0, rows, visible.float())

    def due(self, step: int) -> bool:
        c = self.cfg
        return c.start <= step < self.stop and step % c.every == 0 and step > 0

    def reset_due(self, step: int) -> bool:
        c = self.cfg
        return c.reset_every > 0 and step > 0 and step % c.reset_every == 0 and step < self.stop

    def step(self, step: int, sets: dict[str, GaussianSet], optimizer: torch.optim.Optimizer,
             boxes: dict[str, np.ndarray] | None = None) -> dict[str, GaussianSet]:
        """Densify/prune/reset if due at ``step``; returns the (possibly new) sets."""
        if self.due(step):
            sets = self._densify(sets, optimizer, boxes or {})
        if self.reset_due(step):
            for name, g in sets.items():
                cap = inverse_sigmoid(self.cfg.reset_opacity).to(g.opacity_logits.device)
                new_logit = torch.minimum(g.opacity_logits.detach(), cap)
                sets[name] = replace_param(optimizer, g, "opacity_logits", new_logit, reset_state=True)
        return sets

    def _grow_candidates(self, sets: dict[str, GaussianSet]) -> dict[str, torch.Tensor]:
        cand = {}
        for name, g in sets.items():
            st = self._stats_for(name, len(g), g.means.device)
            mean = st.grad / st.count.clamp_min(1)
            ok = (st.count >= self.cfg.min_views) & (mean > self.cfg.grad_threshold)
            cand[name] = torch.where(ok, mean, torch.full_like(mean, -1.0))
        return cand

    def _densify(self, sets: dict[str, GaussianSet], optimizer: torch.optim.Optimizer,
                 boxes: dict[str, np.ndarray]) -> dict[str, GaussianSet]:
        c = self.cfg
        cand = self._grow_candidates(sets)
        total = sum(len(g) for g in sets.values())
        # Prune first so the budget counts only survivors.
        prune = {name: self._prune_mask(name, g, boxes.get(name)) for name, g in sets.items()}
        total -= sum(int(p.sum()) for p in prune.values())
        room = max(0, c.budget - total)
        scores = torch.cat([torch.where(prune[n], torch.full_like(cand[n], -1.0), cand[n]) for n in sets]) \
            if sets else torch.zeros(0)
        n_want = int((scores > 0).sum())
        grow_all = torch.zeros(len(scores), dtype=torch.bool, device=scores.device)
        if n_want and room:
            k = min(n_want, room)
            grow_all[torch.topk(scores, k).indices] = True
        out, offset, rec = {}, 0, {"clone": 0, "split": 0, "prune": 0}
        for name, g in sets.items():
            n = len(g)
            grow = grow_all[offset: offset + n]
            offset += n
            big = torch.exp(g.log_scales.detach()).max(-1).values > c.split_scale_frac * self.extent
            split, clone = grow & big, grow & ~big
            new = _split_rows(g, split) if bool(split.any()) else None
            cl = g.select(clone) if bool(clone.any()) else None
            keep = ~prune[name] & ~split
            rec["clone"] += int(clone.sum())
            rec["split"] += int(split.sum())
            rec["prune"] += int(prune[name].sum())
            extra = [x for x in (cl, new) if x is not None]
            out[name] = rebuild(optimizer, g, keep, extra)
            self.stats.pop(name, None)
            self._stats_for(name, len(out[name]), out[name].means.device)  # fresh, for the new rows
        rec["total"] = sum(len(g) for g in out.values())
        self.history.append(rec)
        return out

    def _prune_mask(self, name: str, g: GaussianSet, box_lwh: np.ndarray | None) -> torch.Tensor:
        c = self.cfg
        op = g.opacities()
        scale = torch.exp(g.log_scales.detach()).max(-1).values
        bad = (op < c.prune_opacity) | (scale > c.prune_scale_frac * self.extent)
        bad |= ~torch.isfinite(g.means.detach()).all(-1)
        if box_lwh is not None:
            half = torch.as_tensor(np.asarray(box_lwh) / 2 * c.object_box_margin, dtype=g.means.dtype,
                                   device=g.means.device)
            bad |= (g.means.detach().abs() > half).any(-1)
        return bad


def _split_rows(g: GaussianSet, rows: torch.Tensor, n_split: int = 2) -> GaussianSet:
    """Replace each selected Gaussian by ``n_split`` samples of it, scales divided by 1.6."""
    sub = g.select(rows)
    scales = torch.exp(sub.log_scales)
    q = sub.quats / sub.quats.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    w, x, y, z = q.unbind(-1)
    R = torch.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                     2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                     2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1).reshape(-1, 3, 3)
    parts = []
    for _ in range(n_split):
        # drawn by the CPU generator whatever the device: the same samples everywhere, and the
        # checkpoint's CPU RNG state is all a resumed run needs
        offs = torch.randn(scales.shape, dtype=scales.dtype).to(scales.device) * scales
        parts.append(sub.replace(means=sub.means + torch.einsum("nij,nj->ni", R, offs),
                                 log_scales=sub.log_scales - math.log(1.6)))
    out = parts[0]
    for p in parts[1:]:
        out = out.concat(p)
    return out


def rebuild(optimizer: torch.optim.Optimizer, g: GaussianSet, keep: torch.Tensor,
            extra: list[GaussianSet]) -> GaussianSet:
    """New set = rows ``keep`` of ``g`` + ``extra`` rows; Adam moments follow kept rows, new are 0."""
    n_new = sum(len(e) for e in extra)
    tensors = {}
    for name in PARAM_NAMES:
        old = getattr(g, name)
        parts = [old.detach()[keep]] + [getattr(e, name).detach() for e in extra]
        new = torch.cat(parts).contiguous().requires_grad_(True)
        _swap_in_optimizer(optimizer, old, new, lambda s, k=keep, n=n_new: _grow_state(s, k, n))
        tensors[name] = new
    return GaussianSet(**tensors)


def replace_param(optimizer: torch.optim.Optimizer, g: GaussianSet, name: str, value: torch.Tensor,
                  reset_state: bool = False) -> GaussianSet:
    """Set one parameter's values (same shape); optionally zero its Adam moments."""
    old = getattr(g, name)
    new = value.detach().clone().contiguous().requires_grad_(True)
    _swap_in_optimizer(optimizer, old, new, (lambda s: torch.zeros_like(s)) if reset_state else (lambda s: s))
    return g.replace(**{name: new})


def _grow_state(state: torch.Tensor, keep: torch.Tensor, n_new: int) -> torch.Tensor:
    kept = state[keep]
    return torch.cat([kept, torch.zeros((n_new, *state.shape[1:]), dtype=state.dtype, device=state.device)])


def _swap_in_optimizer(optimizer: torch.optim.Optimizer, old: torch.Tensor, new: torch.Tensor, fn) -> None:
    for group in optimizer.param_groups:
        for i, p in enumerate(group["params"]):
            if p is old:
                group["params"][i] = new
                st = optimizer.state.pop(old, None)
                if st:
                    optimizer.state[new] = {k: (fn(v) if isinstance(v, torch.Tensor) and v.ndim > 0 and
                                                v.shape[0] == old.shape[0] else v) for k, v in st.items()}
                return
