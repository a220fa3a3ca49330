"""Densify/prune strategy: growth rules, the budget, optimizer-state surgery, opacity reset."""

from __future__ import annotations

import numpy as np
import torch

from nuav2.splat.densify import DensifyConfig, DensifyStrategy, rebuild
from nuav2.splat.scene_model import GaussianSet


def make_set(n: int, scale: float = 0.05, opacity: float = 0.5, seed: int = 0) -> GaussianSet:
    rng = np.random.default_rng(seed)
    return GaussianSet.create(rng.normal(size=(n, 3)), rng.uniform(size=(n, 3)), np.full(n, scale),
                              opacity=opacity).requires_grad_(True)


def optimizer_for(sets: dict[str, GaussianSet]) -> torch.optim.Adam:
    groups = [{"params": [getattr(g, p)], "name": f"{k}/{p}"} for k, g in sets.items()
              for p in ("means", "quats", "log_scales", "opacity_logits", "sh")]
    return torch.optim.Adam(groups, lr=1e-2)


def take_adam_step(sets: dict[str, GaussianSet], opt: torch.optim.Adam) -> None:
    loss = sum((g.means.sum() + g.opacity_logits.sum() + g.sh.sum() + g.log_scales.sum())
               for g in sets.values())
    loss.backward()
    opt.step()
    opt.zero_grad()


def feed(strategy: DensifyStrategy, name: str, grads: np.ndarray, w: int = 100, h: int = 50) -> None:
    g = torch.tensor(grads, dtype=torch.float32)
    strategy.accumulate(name, g, torch.ones(len(g), dtype=torch.bool), w, h)


def test_clone_small_split_large_and_prune():
    small, large = make_set(4, scale=0.01), make_set(3, scale=1.0, seed=1)
    g = small.concat(large).requires_grad_(True)
    with torch.no_grad():
        g.opacity_logits[1] = -10.0  # opacity ~5e-5: pruned
    sets = {"background": g}
    opt = optimizer_for(sets)
    cfg = DensifyConfig(start=1, every=1, grad_threshold=1e-3, split_scale_frac=0.05, budget=1000)
    st = DensifyStrategy(cfg, extent=10.0)
    grads = np.zeros((7, 2))
    grads[[0, 2, 4, 5], 0] = 0.01  # NDC gradient = 0.01 * 100/2 = 0.5 > threshold
    feed(st, "background", grads)
    out = st.step(1, sets, opt)
    rec = st.history[-1]
    assert rec == {"clone": 2, "split": 2, "prune": 1, "total": 7 - 1 + 2 + 2}
    assert len(out["background"]) == 10
    # Split children are shrunk by 1.6; clones copy their parent exactly.
    scales = torch.exp(out["background"].log_scales.detach()).max(-1).values
    assert int((torch.isclose(scales, torch.tensor(1.0 / 1.6), rtol=1e-4)).sum()) == 4
    assert all(bool(torch.isfinite(t).all()) for t in out["background"].tensors().values())


def test_budget_caps_growth_to_highest_gradients():
    sets = {"background": make_set(10), "obj:a": make_set(5, seed=3)}
    opt = optimizer_for(sets)
    st = DensifyStrategy(DensifyConfig(start=1, every=1, grad_threshold=1e-4, budget=22), extent=10.0)
    bg = np.zeros((10, 2))
    bg[:, 0] = np.linspace(0.001, 0.01, 10)
    ob = np.zeros((5, 2))
    ob[:, 0] = 0.02  # the object's are the largest gradients
    feed(st, "background", bg)
    feed(st, "obj:a", ob)
    out = st.step(1, sets, opt)
    assert sum(len(g) for g in out.values()) == 22
    assert len(out["obj:a"]) == 10  # all 5 object candidates grew before any background one
    assert len(out["background"]) == 12  # then the 2 largest background gradients
    np.testing.assert_allclose(sorted(out["background"].means.detach().numpy()[10:, 0]),
                               sorted(sets["background"].means.detach().numpy()[8:, 0]))
    feed(st, "background", np.full((12, 2), 0.05))
    again = st.step(2, out, opt)
    assert sum(len(g) for g in again.values()) == 22


def test_optimizer_state_follows_rows():
    g = make_set(6)
    sets = {"background": g}
    opt = optimizer_for(sets)
    take_adam_step(sets, opt)
    exp_avg_before = opt.state[g.means]["exp_avg"].clone()
    keep = torch.tensor([True, False, True, True, False, True])
    extra = make_set(2, seed=5)
    new = rebuild(opt, g, keep, [extra])
    st = opt.state[new.means]
    assert g.means not in opt.state
    np.testing.assert_array_equal(st["exp_avg"][:4].numpy(), exp_avg_before[keep].numpy())
    assert float(st["exp_avg"][4:].abs().max()) == 0.0
    assert any(p is new.means for grp in opt.param_groups for p in grp["params"])
    take_adam_step({"background": new}, opt)  # the rebuilt parameters train without shape errors
    assert torch.isfinite(new.means).all()


def test_object_gaussians_outside_box_are_pruned():
    g = make_set(3, scale=0.01)
    with torch.no_grad():
        g.means[:] = torch.tensor([[0.0, 0.0, 0.0], [1.9, 0.0, 0.0], [4.0, 0.0, 0.0]])
    sets = {"obj:car": g}
    opt = optimizer_for(sets)
    st = DensifyStrategy(DensifyConfig(start=1, every=1, object_box_margin=1.0), extent=10.0)
    feed(st, "obj:car", np.zeros((3, 2)))
    out = st.step(1, sets, opt, boxes={"obj:car": np.array([4.0, 2.0, 1.5])})
    np.testing.assert_allclose(out["obj:car"].means.detach().numpy()[:, 0], [0.0, 1.9])


def test_opacity_reset_fires_and_only_lowers():
    g = make_set(4, opacity=0.9)
    with torch.no_grad():
        g.opacity_logits[0] = -6.0  # already below the reset value
    sets = {"background": g}
    opt = optimizer_for(sets)
    take_adam_step(sets, opt)
    st = DensifyStrategy(DensifyConfig(start=10**9, reset_every=3, reset_opacity=0.01), extent=10.0)
    assert st.step(2, sets, opt)["background"] is g  # not due: untouched
    before0 = float(torch.sigmoid(g.opacity_logits.detach()[0]))
    out = st.step(3, sets, opt)["background"]
    op = torch.sigmoid(out.opacity_logits.detach())
    np.testing.assert_allclose(op[1:].numpy(), 0.01, rtol=1e-4)
    np.testing.assert_allclose(float(op[0]), before0, rtol=1e-5)
    assert float(opt.state[out.opacity_logits]["exp_avg"].abs().max()) == 0.0


def test_accumulate_ignores_invisible_and_nonfinite():
    st = DensifyStrategy(DensifyConfig(), extent=10.0)
    grad = torch.tensor([[1.0, 0.0], [float("nan"), 0.0], [1.0, 1.0]])
    vis = torch.tensor([True, True, False])
    st.accumulate("background", grad, vis, 4, 2)
    s = st.stats["background"]
    np.testing.assert_allclose(s.grad.numpy(), [2.0, 0.0, 0.0])
    np.testing.assert_allclose(s.count.numpy(), [1.0, 1.0, 0.0])
    # the same render given as rows of a larger set adds the same amounts to those rows only
    st.accumulate("obj:a", grad, vis, 4, 2, rows=torch.tensor([4, 0, 2]), n=6)
    s = st.stats["obj:a"]
    np.testing.assert_allclose(s.grad.numpy(), [0.0, 0.0, 0.0, 0.0, 2.0, 0.0])
    np.testing.assert_allclose(s.count.numpy(), [1.0, 0.0, 0.0, 0.0, 1.0, 0.0])
