"""Warp mode on a log whose source images have per-image exposure and per-camera white balance: the sources
are harmonised before blending, so the warp scores like it does on the clean log."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from realism_perturb import copy_log, perturb_exposure

from nuav2.evaluate.image_metrics import psnr
from nuav2.geometry import egoS_T_egoT_from_heights
from nuav2.rig import load_rig
from nuav2.warp.provider import WarpConfig, WarpRenderer


@pytest.fixture(scope="module")
def logs(tmp_path_factory) -> tuple[Path, Path]:
    from nuav2.synth import SynthConfig, generate_log

    clean = generate_log(tmp_path_factory.mktemp("harm_clean"), seed=6, config=SynthConfig(seconds=0.6))
    pert = copy_log(clean, tmp_path_factory.mktemp("harm_pert"))
    perturb_exposure(pert, seed=3, drift=0.2, white_balance=0.12)
    return clean, pert


def mean_psnr(log_dir: Path, truth_dir: Path, config: WarpConfig) -> tuple[float, WarpRenderer]:
    from converters.av2 import read_log
    from nuav2.synth import load_world, render_view

    scene, world = read_log(log_dir), load_world(truth_dir)
    rig = load_rig("nuscenes", scale=0.1)
    renderer = WarpRenderer(scene, config)
    egoS_T_egoT = egoS_T_egoT_from_heights(scene.rig.origin_height_m, rig.origin_height_m)
    vals = []
    t = int(scene.sweep_timestamps_ns[3])
    for cam in rig.cameras:
        city_T_cam = scene.city_T_ego_at(t) @ egoS_T_egoT @ cam.ego_T_cam
        img = renderer(cam.channel, cam, city_T_cam, t)
        vals.append(psnr(img / 255.0, render_view(world, cam, city_T_cam, t) / 255.0))
    return float(np.mean(vals)), renderer


def test_harmonised_sources_recover_the_exposure_loss(logs):
    clean, pert = logs
    raw, _ = mean_psnr(pert, clean, WarpConfig(harmonise=None))
    fixed, renderer = mean_psnr(pert, clean, WarpConfig())
    reference, _ = mean_psnr(clean, clean, WarpConfig(harmonise=None))
    assert reference - raw > 3.0  # what the exposure differences cost (measured 6.5 dB)
    assert fixed > reference - 1.0  # harmonised: within 1 dB of the clean log (measured 0.46 dB)
    model, index = renderer.exposure()
    assert model.observations > 10_000 and len(index) == sum(len(f) for f in renderer.frames.values())
    # On the clean log the solve finds (almost) nothing to correct.
    _, clean_renderer = mean_psnr(clean, clean, WarpConfig())
    assert np.abs(clean_renderer.exposure()[0].log_gain).max() < 0.05


def test_a_labelled_actor_hiding_static_points_does_not_set_the_exposure(logs, tmp_path):
    """A truck driving beside a camera covers the static points behind it: without leaving the boxes' pixels
    out, its paint ties that camera's exposure (measured: log gain 0.3-0.5 off on a 15 s `hard` log)."""
    import cv2

    from converters.av2 import read_log
    from nuav2.geometry import translation_T
    from nuav2.warp.depth_proxy import ProxyConfig, box_depth
    from nuav2.warp.harmonise import solve_source_exposure, static_points
    from nuav2.warp.tracks import BoxesAt

    clean, _ = logs
    log = copy_log(clean, tmp_path)
    scene = read_log(log)
    renderer = WarpRenderer(scene)
    channel = "ring_front_center"
    cam = scene.rig.camera(channel)
    frames = renderer.frames[channel]
    truck = {}  # timestamp -> the box 7 m ahead of the camera, 5 m on a side
    for f in frames[:8]:
        t = int(f.timestamp_ns)
        city_T_box = scene.city_T_ego_at(t) @ cam.ego_T_cam @ translation_T(0.0, 0.0, 7.0)
        truck[t] = BoxesAt(np.array([0]), city_T_box[None], np.array([[5.0, 5.0, 5.0]]))
        depth, _ = box_depth(cam, city_T_box @ translation_T(0.0, 0.0, -7.0), city_T_box[None],
                             np.array([[5.0, 5.0, 5.0]]), ProxyConfig())
        img = cv2.imread(f.path)
        img[np.isfinite(depth)] = (60, 60, 230)  # BGR: a red truck
        cv2.imwrite(f.path, img, [cv2.IMWRITE_JPEG_QUALITY, 95])
    assert all(np.isfinite(box_depth(cam, scene.city_T_ego_at(t) @ cam.ego_T_cam, b.city_T_box, b.size_lwh,
                                     ProxyConfig())[0]).mean() > 0.3 for t, b in truck.items())
    empty = BoxesAt(np.zeros(0, np.int64), np.zeros((0, 4, 4)), np.zeros((0, 3)))
    points = static_points(scene, lambda i: renderer.cloud.sweep_points(i)[0])
    cfg = WarpConfig().harmonise
    blind, index = solve_source_exposure(scene, renderer.frames, points, cfg)
    seeing, _ = solve_source_exposure(scene, renderer.frames, points, cfg, lambda t: truck.get(t, empty))
    painted = [index[(channel, j)] for j in range(8)]
    assert np.abs(blind.log_gain[painted]).max() > 0.1  # the truck's red sets the gains
    assert np.abs(seeing.log_gain[painted]).max() < 0.05  # left out: the clean log's (near) unit gain
