"""Reconstruction on a CUDA GPU with gsplat against the same reconstruction on the CPU (issue 14).

Skipped without CUDA and gsplat (every CI job here); ``python -m nuav2.bench.gpu_check`` runs it
on a GPU machine. gsplat accumulates gradients with atomics, so a CUDA run is not bit-reproducible:
the comparison is the target-rig PSNR against the synthetic world's truth, within 0.5 dB.
"""

from __future__ import annotations

import json

import device_scenes as ds
import pytest
import torch

from nuav2.bench.recon import target_rig_scores
from nuav2.recon import reconstruct, render_provider
from nuav2.splat.gsplat_backend import gsplat_available
from nuav2.splat.init import initial_scene, source_views
from nuav2.splat.train import CHECKPOINT_FILE, Trainer
from nuav2.synth import load_world

CUDA, WHY_NOT = gsplat_available()
pytestmark = pytest.mark.skipif(not CUDA, reason=f"needs a CUDA GPU with gsplat: {WHY_NOT}")

ITERATIONS = 200


@pytest.fixture(scope="module")
def tiny_log(tmp_path_factory):
    from nuav2.synth import generate_log

    return generate_log(tmp_path_factory.mktemp("cuda_log"), seed=ds.TINY_SEED, config=ds.TINY_LOG)


@pytest.fixture(scope="module")
def tiny_scene(tiny_log):
    from converters.av2 import read_log

    return read_log(tiny_log)


@pytest.fixture(scope="module")
def both(tiny_scene):
    """The tiny log reconstructed from every ring camera on the CPU and on CUDA, same config."""
    return {device: reconstruct(tiny_scene, ds.tiny_recon_config(ITERATIONS, channels=None, device=device),
                                progress=False) for device in ("cpu", "cuda")}


def test_cuda_reconstruction_is_within_half_a_db_of_the_cpu_one(both, tiny_scene, tiny_log):
    gpu = both["cuda"]
    assert gpu.info["device"] == "cuda:0" and gpu.device.type == "cuda"
    assert gpu.background.means.is_cuda and gpu.sky.texture.is_cuda
    assert all(o.gaussians.means.is_cuda for o in gpu.objects)
    world = load_world(tiny_log)
    scores = {d: target_rig_scores(s, tiny_scene, world, scale=1 / 16, n_times=3, paint=False)
              for d, s in both.items()}
    print(json.dumps({d: round(s["psnr_db"], 3) for d, s in scores.items()}))
    assert scores["cpu"]["psnr_db"] > 15.0
    assert abs(scores["cuda"]["psnr_db"] - scores["cpu"]["psnr_db"]) < 0.5


def test_render_mode_renders_on_the_gpu_it_trained_on(both, tiny_scene):
    from nuav2.rig import load_rig
    from nuav2.splat.render_target import target_city_T_cams

    source = render_provider(both["cuda"], min_confidence=0.0)
    assert source.device == "cuda:0"
    rig = load_rig("nuscenes", scale=1 / 16).with_origin_height(0.0)
    t = int(tiny_scene.sweep_timestamps_ns[1])
    poses = target_city_T_cams(tiny_scene, rig, t)
    cam = rig.cameras[0]
    img = source.renderer(cam.channel, cam, poses[cam.channel], t)
    assert img.dtype.name == "uint8" and img.shape == (cam.height, cam.width, 3) and img.std() > 1
    assert 0.0 <= source.renderer.coverage[cam.channel][t] <= 1.0


def test_checkpoints_move_between_cuda_and_cpu(tiny_scene, tmp_path):
    views = [v for v in source_views(tiny_scene, 1.0) if v.channel in ds.CHANNELS]
    init = initial_scene(tiny_scene, views, ds.TINY_INIT, sh_degree=1, progress=False)
    cfg = ds.tiny_train_config(iterations=8)
    for first, then in (("cuda", "cpu"), ("cpu", "cuda")):
        folder = tmp_path / f"{first}_to_{then}"
        a = Trainer(ds.copy_scene(init.scene).to(first), tiny_scene, views, init.sky_masks, cfg)
        a.run(progress=False, checkpoint_dir=folder, stop_at=4)
        state = torch.load(folder / CHECKPOINT_FILE, weights_only=False)     # CPU tensors only
        assert state["scene"]["background"]["means"].device.type == "cpu"
        b = Trainer(ds.copy_scene(init.scene).to(then), tiny_scene, views, init.sky_masks, cfg)
        b.load(folder / CHECKPOINT_FILE)
        assert b.step == 4 and b.splat.device.type == then
        assert torch.equal(b.splat.background.means.detach().cpu(), state["scene"]["background"]["means"])
        assert all(s.device.type == then for st in b.optimizer.state.values() for s in st.values() if s.ndim)
        report = b.run(progress=False)
        assert report.steps == 8 and all(torch.isfinite(torch.tensor(b.losses)))
