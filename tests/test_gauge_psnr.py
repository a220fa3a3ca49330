"""The exposure gauge of the world scores: one gain per colour channel per log is forgiven, drift is not."""

from __future__ import annotations

import numpy as np

from nuav2.evaluate.against_world import RegionScores
from nuav2.evaluate.image_metrics import psnr
from nuav2.rig import CameraSpec
from nuav2.synth import REGION_LABELS


def _camera(channel: str) -> CameraSpec:
    K = np.array([[40.0, 0, 32], [0, 40.0, 24], [0, 0, 1]])
    return CameraSpec(channel, 64, 48, K, np.eye(4))


def _truth_and_labels(seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    truth = rng.integers(30, 200, size=(48, 64, 3)).astype(np.uint8)
    labels = np.full((48, 64), REGION_LABELS["ground"], np.uint8)
    labels[:16] = REGION_LABELS["sky"]
    return truth, labels


def _scores(gain_of_image) -> dict:
    scores = RegionScores()
    for i in range(6):
        truth, labels = _truth_and_labels(i)
        g = np.asarray(gain_of_image(i), np.float64)
        img = np.clip(np.rint(truth * g), 0, 255).astype(np.uint8)
        scores.add(_camera(f"CAM_{i % 2}"), np.eye(4), img, truth, labels)
    return scores.summary()


def test_a_constant_per_channel_gain_is_the_gauge() -> None:
    s = _scores(lambda i: [0.9, 0.95, 0.85])
    assert s["psnr_db"]["whole"] < 27.0  # raw PSNR charges the log's offset ...
    assert s["psnr_gauge_db"]["whole"] > 45.0  # ... the gauge PSNR leaves only the rounding
    assert np.allclose(s["gauge_log_gain"], -np.log([0.9, 0.95, 0.85]), atol=0.01)


def test_gains_that_differ_between_images_still_cost() -> None:
    s = _scores(lambda i: [0.8 + 0.08 * i] * 3)
    assert s["psnr_gauge_db"]["whole"] < 30.0
    assert s["psnr_gauge_db"]["whole"] >= s["psnr_db"]["whole"] - 1e-6


def test_gauge_psnr_equals_raw_psnr_at_unit_gain() -> None:
    s = _scores(lambda i: [1.0, 1.0, 1.0])
    truth, _ = _truth_and_labels(0)
    assert s["gauge_log_gain"] == [0.0, 0.0, 0.0]
    assert s["psnr_gauge_db"]["ground"] == s["psnr_db"]["ground"] == round(psnr(truth, truth, 255.0), 4)
    half = _scores(lambda i: [0.5, 0.5, 0.5])  # the gauge is fitted, not assumed: 2x back
    assert np.allclose(half["gauge_log_gain"], np.log(2.0), atol=0.01)
