"""The trainer on gsplat's output conventions, without a GPU (issue 14).

``backend="gsplat-reference"`` renders through gsplat's own PyTorch path on the CPU behind the very
input and output conversions the CUDA backend uses (:mod:`nuav2.splat.gsplat_backend`), so what
densification reads (``means2d`` gradients, ``radii``, visibility) arrives as gsplat produces it.
Against the CPU kernels on the same scene and views: the same meta layout, the same NDC gradient
scale per Gaussian, the same densification decisions, and the loss goes down.
"""

from __future__ import annotations

from dataclasses import replace

import device_scenes as ds
import pytest
import torch

from nuav2.splat.densify import DensifyConfig
from nuav2.splat.gsplat_reference import gsplat_installed
from nuav2.splat.init import initial_scene, source_views
from nuav2.splat.scene_model import SplatScene
from nuav2.splat.train import Trainer

pytestmark = pytest.mark.skipif(not gsplat_installed(),
                                reason="gsplat is not installed (pip install -e '.[dev]' brings it)")

BACKENDS = ("cpu", "gsplat-reference")
STEPS = 6  # gsplat's torch path costs ~0.5 s a step here; densification runs at the last one


@pytest.fixture(scope="module")
def seeded(tmp_path_factory):
    """(scene log, two views at half the tiny log's resolution (48x64), seeded scene, sky masks)."""
    scene = ds.tiny_scene(tmp_path_factory.mktemp("gsplat_conventions"))
    views = [v for v in source_views(scene, 0.5) if v.channel in ds.CHANNELS]
    seeds = replace(ds.TINY_INIT, max_background=1500)
    init = initial_scene(scene, views, seeds, sh_degree=0, progress=False)
    return scene, views[:: len(views) // 2][:2], init.scene, init.sky_masks


def _trainer(seeded, backend: str) -> Trainer:
    scene, views, splat, sky = seeded
    copy = ds.copy_scene(splat)
    copy.backend = backend
    densify = DensifyConfig(start=STEPS - 1, every=STEPS - 1, stop=STEPS, budget=50_000, reset_every=0)
    # lambda_flat=0: the loss compared is the rasterizer's (photometric, depth, sky); the flatness term is
    # plain torch on the parameters, the same on every backend, and would outweigh it on this toy scene
    cfg = ds.tiny_train_config(STEPS, pyramid=(1.0,), pyramid_until=(), densify=densify, eval_every=0,
                               lambda_flat=0.0)
    return Trainer(copy, scene, views, sky, cfg)


def _render(splat: SplatScene, view):
    out = splat.render(view.cam, view.city_T_cam, view.timestamp_ns)
    out.meta["means2d"].retain_grad()
    out.rgb.square().mean().backward()
    return out


def test_gsplat_meta_reaches_the_trainer_in_the_cpu_backends_layout(seeded):
    _, views, splat, _ = seeded
    cpu, ref = (_render(_trainer(seeded, b).splat, views[0]) for b in BACKENDS)
    assert ref.meta["backend"] == "gsplat-reference" and cpu.meta["backend"] == "cpu"
    assert torch.equal(cpu.index, ref.index)
    for out in (cpu, ref):
        n = len(out.index)
        assert out.meta["radii"].dtype == torch.int32 and out.meta["radii"].shape == (1, n, 2)
        assert out.meta["means2d"].shape == (1, n, 2) and out.meta["means2d"].grad.shape == (1, n, 2)
        assert torch.equal(out.meta["visible"], (out.meta["radii"] > 0).any(-1))
        hidden = ~out.meta["visible"][0]
        assert (out.meta["depths"][0][hidden] == 0).all() and (out.meta["conics"][0][hidden] == 0).all()
    vis_cpu, vis_ref = cpu.meta["visible"][0], ref.meta["visible"][0]
    # gsplat's torch path bounds radii by 3.33 sigma without the opacity cut, so it calls a few more visible
    assert torch.equal(vis_cpu & vis_ref, vis_cpu) and int(vis_ref.sum()) < 1.1 * int(vis_cpu.sum())
    g_cpu, g_ref = cpu.meta["means2d"].grad[0], ref.meta["means2d"].grad[0]
    assert (g_ref[vis_ref & ~vis_cpu] == 0).all()
    # same pixel units and sign: per-Gaussian gradients agree to float32 summation order
    scale = g_cpu.abs().max()
    assert scale > 0 and ((g_cpu - g_ref).abs().max() / scale) < 1e-3
    diff = (cpu.rgb - ref.rgb).abs().detach()       # float32: a rare pixel flips an alpha threshold
    assert diff.max() < 1e-3 and (diff > 1e-4).float().mean() < 1e-2


def test_training_on_gsplat_conventions_densifies_like_the_cpu_backend(seeded):
    runs = {}
    for backend in BACKENDS:
        tr = _trainer(seeded, backend)
        losses = [tr.train_step()[0] for _ in range(STEPS - 1)]
        stats = {k: (s.grad.clone(), s.count.clone()) for k, s in tr.strategy.stats.items()}
        losses.append(tr.train_step()[0])               # densifies
        runs[backend] = (losses, stats, tr.strategy.history)
    (l_cpu, s_cpu, h_cpu), (l_ref, s_ref, h_ref) = runs["cpu"], runs["gsplat-reference"]
    assert l_ref[-1] < 0.9 * l_ref[0], l_ref
    assert max(abs(a - b) / a for a, b in zip(l_cpu, l_ref)) < 1e-3
    assert s_cpu.keys() == s_ref.keys() and "background" in s_cpu
    for name in s_cpu:
        (g0, c0), (g1, c1) = s_cpu[name], s_ref[name]
        assert c1.sum() >= c0.sum()
        if not c0.sum():
            continue
        # the NDC gradient the threshold (2e-4) is compared with: same scale, Gaussian by Gaussian
        assert abs(float(g1.sum() / g0.sum()) - 1.0) < 1e-3, name
        both = (c0 > 0) & (c1 > 0) & (g0 > 1e-6)
        ratio = (g1[both] / c1[both]) / (g0[both] / c0[both])
        assert 0.99 < float(ratio.median()) < 1.01, name
    for rec_cpu, rec_ref in zip(h_cpu, h_ref, strict=True):
        for key in ("clone", "split", "total"):
            assert abs(rec_ref[key] - rec_cpu[key]) <= 0.02 * rec_cpu[key] + 2, (key, rec_cpu, rec_ref)
    assert h_cpu[0]["split"] + h_cpu[0]["clone"] > 100
