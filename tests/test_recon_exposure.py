"""Exposure harmonisation: the solver against known gains, and render-mode seeding on a log whose images were
given per-image exposure and per-camera white balance (tests/realism_perturb.py)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from realism_perturb import copy_log, perturb_exposure

from nuav2.exposure import (
    ExposureModel,
    Observations,
    frames_to_observe,
    interpolate_log_gains,
    solve_exposure,
)
from nuav2.rig import CameraSpec


def synthetic_observations(seed: int, outliers: float = 0.05):
    rng = np.random.default_rng(seed)
    n_img, n_pt, n_cam = 60, 3000, 6
    cams = np.arange(n_img) % n_cam
    log_gain = rng.normal(0, 0.15, (n_img, 3))
    log_gain -= log_gain.mean(0)
    vig = np.array([-0.3, 0.05])
    albedo = rng.uniform(0.1, 0.7, (n_pt, 3))
    obs = Observations()
    for v in range(n_img):
        p = rng.choice(n_pt, 400, replace=False)
        rho2 = rng.uniform(0, 1, 400)
        log_f = log_gain[v] + (vig[0] * rho2 + vig[1] * rho2**2)[:, None]
        c = albedo[p] * np.exp(log_f + rng.normal(0, 0.02, (400, 3)))
        bad = rng.random(400) < outliers
        c[bad] = rng.uniform(0.05, 0.95, (int(bad.sum()), 3))  # moving things, occlusion mistakes
        obs.add(v, p, c, rho2)
    return obs, cams, log_gain, vig


def test_solver_recovers_gains_and_vignetting_despite_outliers():
    obs, cams, log_gain, vig = synthetic_observations(0)
    model = solve_exposure(obs, cams)
    assert np.abs(model.log_gain - log_gain).max() < 0.02  # 2 %, with 2 % colour noise and 5 % outliers
    assert np.abs(model.vignetting - vig).max() < 0.05  # (every camera has the same fall-off here)
    assert np.allclose(model.log_gain.mean(0), 0.0, atol=1e-9)  # the reference: the log's mean exposure
    assert 0.8 < model.inliers / model.observations <= 0.95  # the outliers are among the dropped


def test_solver_without_shared_points_is_identity():
    obs = Observations()
    obs.add(0, np.arange(10), np.full((10, 3), 0.5), np.zeros(10))
    obs.add(1, np.arange(10, 20), np.full((10, 3), 0.2), np.zeros(10))
    model = solve_exposure(obs, np.array([0, 1]))
    assert np.all(model.log_gain == 0) and model.observations == 0


def test_correct_undoes_a_known_factor():
    K = np.array([[40.0, 0, 31.5], [0, 40.0, 23.5], [0, 0, 1]])
    cam = CameraSpec("c", 64, 48, K, np.eye(4))
    model = ExposureModel(np.array([[0.2, -0.1, 0.05]]), np.array([[-0.3, 0.0]]), np.array([0]))
    rng = np.random.default_rng(1)
    ref = rng.uniform(0.1, 0.6, (48, 64, 3)).astype(np.float32)
    observed = ref * model.factor(0, cam.K, cam.width, cam.height)
    np.testing.assert_allclose(model.correct(observed, 0, cam.K), ref, rtol=1e-5)
    # the corner is darker than the centre by exp(-0.3 * 1)
    f = model.factor(0, cam.K, cam.width, cam.height)
    assert f[0, 0, 0] < f[24, 32, 0] * np.exp(-0.25)
    # uint8 images take the one-pass path: the same rounding and clipping as the float formula
    u8 = rng.integers(0, 256, (48, 64, 3), dtype=np.uint8)
    expect = np.clip(u8.astype(np.float32) / f + 0.5, 0, 255).astype(np.uint8)
    np.testing.assert_array_equal(model.correct(u8, 0, cam.K), expect)


def test_frames_to_observe_keep_the_rate_and_both_ends():
    t = np.arange(41) * 50_000_000 + 7  # 20 Hz for 2 s
    picked = frames_to_observe(t, 5.0)
    assert picked[0] == 0 and picked[-1] == 40
    assert np.all(np.diff(t[picked][:-1]) == 200_000_000)  # every 4th frame
    jittered = t + np.random.default_rng(0).integers(-3_000_000, 3_000_000, len(t))
    assert len(frames_to_observe(jittered, 5.0)) == len(picked)  # a few ms of jitter changes nothing
    np.testing.assert_array_equal(frames_to_observe(t, 0.0), np.arange(41))  # 0: every frame
    np.testing.assert_array_equal(frames_to_observe(t[:2], 5.0), [0, 1])
    short = frames_to_observe(t[:13], 2.5, min_frames=12)  # 0.6 s: 2.5 Hz would read 3 images
    assert len(short) >= 12 and short[0] == 0 and short[-1] == 12
    assert len(frames_to_observe(t, 2.5, min_frames=12)) == 11  # 2 s: 5.5 Hz at most -> every 4th frame


def test_gains_of_unobserved_images_are_linear_in_time_per_camera():
    cams = np.array([0, 0, 0, 1, 1, 1, 1])
    t = np.array([0, 50, 100, 0, 50, 100, 150]) * 1_000_000
    observed = np.array([0, 2, 3, 6])  # each camera's ends
    gains = np.array([[0.0] * 3, [0.2] * 3, [-0.3] * 3, [0.3] * 3])
    solved = ExposureModel(gains, np.zeros((2, 2)), cams[observed])
    full = interpolate_log_gains(solved, observed, t, cams)
    np.testing.assert_allclose(full.log_gain[:, 0], [0.0, 0.1, 0.2, -0.3, -0.1, 0.1, 0.3])
    assert full.camera_of_image.tolist() == cams.tolist() and full.vignetting.shape == (2, 2)


# ---- render mode on a log with exposure differences ----------------------------------------------------

@pytest.fixture(scope="module")
def logs(tmp_path_factory) -> tuple[Path, Path, dict]:
    from nuav2.synth import SynthConfig, generate_log

    cfg = SynthConfig(seconds=0.5, image_scale=1 / 16, lidar_azimuth_steps=256, n_parked=2, n_moving=1,
                      n_pedestrians=0, map_margin_m=30.0)
    clean = generate_log(tmp_path_factory.mktemp("expo_clean"), seed=4, config=cfg)
    pert = copy_log(clean, tmp_path_factory.mktemp("expo_pert"))
    applied = perturb_exposure(pert, seed=2, drift=0.2, white_balance=0.12)
    return clean, pert, applied


def test_seeding_solves_the_applied_exposure_and_harmonises_the_seeds(logs):
    from converters.av2 import read_log
    from nuav2.bench.recon import target_rig_scores
    from nuav2.splat.init import InitConfig, initial_scene, source_views
    from nuav2.synth import load_world

    clean, pert, applied = logs
    scene = read_log(pert)
    views = source_views(scene, 1.0)
    init = InitConfig(max_background=20_000, ground_spacing_m=0.4, ground_radius_m=15.0)
    res = initial_scene(scene, views, init, sh_degree=0)
    solved = res.exposure.log_gain
    truth = np.log(np.array([applied[v.channel][v.timestamp_ns] for v in views]))
    err = (solved - solved.mean(0)) - (truth - truth.mean(0))
    assert np.sqrt(np.mean(err**2)) < 0.03  # applied: log std ~0.2; measured 0.015
    # Seeding on two threads (views projected in parallel, merged in order) gives the same bytes.
    two = initial_scene(scene, source_views(scene, 1.0), init, sh_degree=0, threads=2)
    np.testing.assert_array_equal(two.exposure.log_gain, solved)
    for a, b in ((res.scene.background, two.scene.background),
                 *((x.gaussians, y.gaussians) for x, y in zip(res.scene.objects, two.scene.objects))):
        for name, tensor in a.tensors().items():
            assert np.array_equal(tensor.detach().numpy(), b.tensors()[name].detach().numpy()), name
    assert all(np.array_equal(res.sky_masks[k], two.sky_masks[k]) for k in res.sky_masks)
    # Seeds coloured from harmonised images render the target rig closer to the truth than seeds coloured
    # from the raw ones (no training: seeding alone shows it).
    raw = initial_scene(scene, source_views(scene, 1.0), replace(init, exposure=None), sh_degree=0)
    world = load_world(clean)
    on = target_rig_scores(res.scene, scene, world, scale=1 / 16, n_times=2, paint=False)["psnr_db"]
    off = target_rig_scores(raw.scene, scene, world, scale=1 / 16, n_times=2, paint=False)["psnr_db"]
    assert on > off + 0.5, (on, off)  # measured 15.76 against 14.95 dB
