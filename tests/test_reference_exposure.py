"""The cameras' recorded exposure reproduces the log's images, and scores with the log's true mean exposure
taken out charge drift but not the log's one unobservable offset from unit exposure."""

from __future__ import annotations

import json

import numpy as np
import pytest

from nuav2.evaluate.against_world import RegionScores
from nuav2.maptr.dataset import load_image_rgb
from nuav2.rig import CameraSpec
from nuav2.synth import REGION_LABELS, SynthConfig, generate_log, load_world, render_view
from nuav2.synth.camera_effects import CAMERA_EFFECTS_FILE, expose, log_reference_gain, reference_gain


@pytest.fixture(scope="module")
def exposed_log(tmp_path_factory):
    cfg = SynthConfig.for_preset("easy", seconds=0.3, image_scale=0.0625, exposure=True, camera_noise=False)
    return generate_log(tmp_path_factory.mktemp("ref_exposure"), seed=2, config=cfg)


def test_recorded_gains_reproduce_the_images_and_give_the_reference(exposed_log):
    record = json.loads((exposed_log / CAMERA_EFFECTS_FILE).read_text())
    world = load_world(exposed_log)
    cams = record["cameras"]
    assert sorted(cams) == sorted(world.camera_channels)
    gains = []
    for ch, c in cams.items():
        stamps = sorted(int(p.stem) for p in (exposed_log / "sensors" / "cameras" / ch).glob("*.jpg"))
        assert [ts for ts, _ in c["images"]] == stamps  # one record per written image, in time order
        gains += [g * np.asarray(c["white_balance"]) for _, g in c["images"]]
    spread = np.ptp(np.log([g[1] for g in gains]))
    assert spread > 0.05  # the cameras really disagree, so the checks below could fail
    np.testing.assert_allclose(reference_gain(cams), np.exp(np.mean(np.log(gains), axis=0)), rtol=1e-12)
    np.testing.assert_allclose(log_reference_gain(exposed_log), reference_gain(cams))

    ch = "ring_front_center"
    cam = world.rig.camera(ch)
    v, u = np.mgrid[0:cam.height, 0:cam.width]
    r2 = ((u - cam.K[0, 2]) / cam.K[0, 0]) ** 2 + ((v - cam.K[1, 2]) / cam.K[1, 1]) ** 2
    vig = (1.0 - cams[ch]["vignette"]) + cams[ch]["vignette"] / (1.0 + r2) ** 2  # the lens' cos^4 fall-off
    for ts, g in cams[ch]["images"][::3]:
        clean = render_view(world, cam, world.city_T_ego_at(ts) @ cam.ego_T_cam, ts).astype(float)
        written = load_image_rgb(str(exposed_log / "sensors" / "cameras" / ch / f"{ts}.jpg")).astype(float)
        ok = ((clean > 20) & (clean < 200) & (written > 20) & (written < 235)).all(-1)
        ratio = np.median(2.2 * np.log(written[ok] / clean[ok]) - np.log(vig[ok])[:, None], axis=0)
        np.testing.assert_allclose(ratio, np.log(g * np.asarray(cams[ch]["white_balance"])), atol=0.03)


def test_a_clean_log_has_no_record(tmp_path):
    cfg = SynthConfig.for_preset("easy", seconds=0.2, image_scale=0.0625)
    log = generate_log(tmp_path, seed=2, config=cfg)
    assert not (log / CAMERA_EFFECTS_FILE).exists() and log_reference_gain(log) is None


def _scores(reference, image_gain) -> dict:
    K = np.array([[40.0, 0, 32], [0, 40.0, 24], [0, 0, 1]])
    scores = RegionScores(reference_gain=reference)
    for i in range(4):
        truth = np.random.default_rng(i).integers(30, 200, size=(48, 64, 3)).astype(np.uint8)
        labels = np.full((48, 64), REGION_LABELS["ground"], np.uint8)
        img = np.clip(np.rint(expose(truth, image_gain(i))), 0, 255).astype(np.uint8)
        scores.add(CameraSpec(f"CAM_{i % 2}", 64, 48, K, np.eye(4)), np.eye(4), img, truth, labels)
    return scores.summary()


def test_reference_psnr_forgives_the_true_mean_exposure_only():
    ref = np.array([0.8, 0.9, 0.75])
    at_ref = _scores(ref, lambda i: ref)
    assert at_ref["psnr_db"]["whole"] < 30.0  # the raw score charges the offset from unit exposure ...
    assert at_ref["psnr_ref_db"]["whole"] > 45.0  # ... the reference score only the rounding
    drift = _scores(ref, lambda i: ref * (0.7 + 0.2 * i))  # images off their reference still cost
    assert drift["psnr_ref_db"]["whole"] < 32.0
    wrong = _scores(ref * 1.1, lambda i: ref)  # a reference that is not the images' is not forgiven
    assert wrong["psnr_ref_db"]["whole"] < 35.0
    unit = _scores(None, lambda i: np.ones(3))  # no record: the truth is at the images' exposure
    assert unit["psnr_ref_db"] == unit["psnr_db"]
