"""The cool-down after a held-out plateau: learning rates annealed to their end, then stop; resumable.

A run that stops at a plateau long before its cap left its position learning rate where a fraction of
the cap put it; the cool-down finishes the schedule (docs/reconstruction.md, "A cool-down after the
plateau").
"""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
import torch
from test_recon_pipeline import TINY_INIT, TINY_LOG

from converters.av2 import read_log
from nuav2.recon import ReconConfig, split_views
from nuav2.splat.densify import DensifyConfig
from nuav2.splat.init import initial_scene, source_views
from nuav2.splat.optimizer import base_lr
from nuav2.splat.train import CHECKPOINT_FILE, TrainConfig, Trainer
from nuav2.synth import generate_log

# Every measurement after the first is "no gain" (100 dB asked), densification is over by step 20 and
# the plateau is not called before full resolution (step 40): the cool-down runs steps 40-59.
CFG = TrainConfig(iterations=400, pyramid=(0.5, 1.0), pyramid_until=(0.1,),
                  densify=DensifyConfig(start=8, every=8, stop=20, budget=25_000, reset_every=0),
                  eval_every=10, patience=1, min_delta_db=100.0,
                  cooldown_frac=0.5, cooldown_min=10, cooldown_lr_end=0.1)


@pytest.fixture(scope="module")
def tiny_scene(tmp_path_factory):
    return read_log(generate_log(tmp_path_factory.mktemp("cooldown_synth"), seed=3, config=TINY_LOG))


def trainer(scene, cfg: TrainConfig = CFG) -> Trainer:
    train, held = split_views(source_views(scene, 1.0), 5)
    init = initial_scene(scene, train, TINY_INIT, sh_degree=0, other_views=held)
    return Trainer(init.scene, scene, train, init.sky_masks, cfg, validation=held)


def test_a_plateau_starts_a_cool_down_that_ends_the_schedule_and_resumes_exactly(tiny_scene, tmp_path):
    a = trainer(tiny_scene)
    rep = a.run(progress=False)
    assert rep.stop_reason == "plateau" and rep.cooldown == [40, 20] and rep.steps == 60
    assert [s for s, _ in rep.validation] == [10, 20, 30, 40, 60]  # none measured while cooling down
    assert all(math.isfinite(v) for _, v in rep.validation)
    a._set_lr()  # the schedule where the run ended: positions at their final rate, the rest at 0.1 x
    lrs = {g["name"]: g["lr"] for g in a.optimizer.param_groups}
    assert lrs["background/means"] == pytest.approx(base_lr("background/means", CFG, a.extent) * 0.01)
    assert lrs["sky"] == pytest.approx(CFG.lr_sky * 0.01)
    assert lrs["background/opacity_logits"] == pytest.approx(CFG.lr_opacity * 0.1)
    assert lrs["background/sh"] == pytest.approx(CFG.lr_sh_dc * 0.1)

    b = trainer(tiny_scene)
    b.run(progress=False, checkpoint_dir=tmp_path, stop_at=50)  # "killed" in the middle of the cool-down
    c = trainer(tiny_scene)
    c.load(tmp_path / CHECKPOINT_FILE)
    assert c.step == 50 and c.cool == (40, 20)
    rep_c = c.run(progress=False)
    assert rep_c.cooldown == [40, 20] and rep_c.steps == 60 and rep_c.validation == rep.validation
    for name, t in a.splat.background.tensors().items():
        assert torch.equal(t, c.splat.background.tensors()[name]), name


def test_without_a_cool_down_the_plateau_stops_at_once(tiny_scene):
    rep = trainer(tiny_scene, replace(CFG, cooldown_frac=0.0)).run(progress=False)
    assert rep.stop_reason == "plateau" and rep.cooldown is None and rep.steps == 40


def test_the_plain_extra_steps_control_keeps_every_rate_where_the_plateau_left_it(tiny_scene):
    cfg = replace(CFG, cooldown_lr_end=1.0, cooldown_positions=False)
    t = trainer(tiny_scene, cfg)
    rep = t.run(progress=False)
    assert rep.cooldown == [40, 20] and rep.steps == 60
    t._set_lr()
    lrs = {g["name"]: g["lr"] for g in t.optimizer.param_groups}
    at_plateau = CFG.lr_final_frac ** (40 / CFG.iterations)  # the decay step 40 of the 400-step cap reached
    assert lrs["background/means"] == pytest.approx(base_lr("background/means", cfg, t.extent) * at_plateau)
    assert lrs["sky"] == pytest.approx(CFG.lr_sky * at_plateau)
    assert lrs["background/opacity_logits"] == pytest.approx(CFG.lr_opacity)


def test_the_default_preset_cools_down_and_fast_is_time_boxed_instead():
    assert ReconConfig.default().train.cooldown_frac > 0
    assert ReconConfig.fast().train.cooldown_frac == 0
