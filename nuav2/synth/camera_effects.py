"""What a real camera does to the clean render, for the images written into the AV2 log only.

With the ``exposure`` factor each ring camera has its own auto-exposure that chases a target
brightness with a lag and drifts over seconds, its own white balance, lens vignetting, and
sensor noise (read noise plus shot noise), and the JPEGs are more compressed (``camera_noise=False``
in the config keeps the gains and drops the noise and the extra compression, to tell their costs
apart). The ground-truth renderer (render.py) never applies any of this: the truth is unit
exposure, neutral white balance, no vignetting, no noise. What the cameras did is recorded
(:meth:`CameraEffects.describe`, written beside the log as ``CAMERA_EFFECTS_FILE``) so that benchmarks
can take the log's own mean exposure out of the images before scoring them against the truth
(:func:`reference_gain`, :func:`expose`).
"""

from __future__ import annotations

import json
import zlib
from pathlib import Path

import numpy as np

from nuav2.rig import CameraSpec

CAMERA_EFFECTS_FILE = "synthetic_camera_effects.json"  # beside synthetic_world.json in a log with `exposure`

GAMMA = 2.2
AE_TARGET = 0.17  # mean linear luminance the auto-exposure aims for
AE_RATE = 0.2  # fraction of the way to the target gain per image (20 Hz)
GAIN_RANGE = (0.5, 2.0)
EFFECTS_JPEG_QUALITY = 85
READ_NOISE = 1.2  # 8-bit units
SHOT_NOISE = 0.12  # x sqrt(8-bit value)


class CameraEffects:
    """Per-camera exposure state; :meth:`apply` must see each camera's images in time order."""

    def __init__(self, seed: int, channels: list[str], noise: bool = True):
        self.seed = seed
        self.noise = noise  # read and shot noise (False: the exposure, white balance and vignetting alone)
        self.params = {}
        for i, ch in enumerate(sorted(channels)):
            rng = np.random.default_rng([seed, 200, i])
            self.params[ch] = {
                "target": AE_TARGET * rng.uniform(0.85, 1.2),
                "wb": np.array([rng.uniform(0.9, 1.1), 1.0, rng.uniform(0.88, 1.1)]),
                "drift": (rng.uniform(0.06, 0.15), rng.uniform(3.0, 9.0), rng.uniform(0, 2 * np.pi)),
                "vignette": rng.uniform(0.4, 0.65),
            }
        self.gain: dict[str, float] = {}
        self.applied: dict[str, list[tuple[int, float]]] = {ch: [] for ch in sorted(channels)}  # (ts, gain)
        self._vignette: dict[str, np.ndarray] = {}

    def gain_for(self, channel: str, linear: np.ndarray, valid: np.ndarray, t_s: float) -> float:
        """The exposure gain of this image: the lagged auto-exposure times a slow drift."""
        p = self.params[channel]
        sub, ok = linear[::4, ::4], valid[::4, ::4]  # metering on a sparse grid, as cameras do
        lum = sub[ok] @ np.array([0.2126, 0.7152, 0.0722], np.float32) if ok.any() else np.array([AE_TARGET])
        want = p["target"] / max(float(np.mean(lum)), 1e-3)
        g = self.gain.get(channel, want)
        g = g + AE_RATE * (want - g)
        self.gain[channel] = g
        amp, period, phase = p["drift"]
        return float(np.clip(g * (1.0 + amp * np.sin(2 * np.pi * t_s / period + phase)), *GAIN_RANGE))

    def apply(self, cam: CameraSpec, img: np.ndarray, t_s: float, timestamp_ns: int) -> np.ndarray:
        """The camera's image of the clean render ``img`` (uint8 RGB) at ``t_s`` seconds into the log."""
        p = self.params[cam.channel]
        linear = to_linear(img)
        valid = ~cam.ego_mask() if cam.ego_mask_polygons else np.ones(img.shape[:2], bool)
        gain = self.gain_for(cam.channel, linear, valid, t_s)
        self.applied[cam.channel].append((int(timestamp_ns), gain))
        vig = self._vignette.get(cam.channel)
        if vig is None or vig.shape != img.shape[:2]:
            h, w = img.shape[:2]
            v, u = np.mgrid[0:h, 0:w].astype(np.float32)
            K = cam.K
            r2 = ((u - K[0, 2]) / K[0, 0]) ** 2 + ((v - K[1, 2]) / K[1, 1]) ** 2
            vig = ((1.0 - p["vignette"]) + p["vignette"] / (1.0 + r2) ** 2).astype(
                np.float32
            )  # cos^4 falloff
            self._vignette[cam.channel] = vig
        out = to_display(linear * (gain * vig)[..., None] * p["wb"][None, None, :].astype(np.float32))
        if not self.noise:
            return np.clip(np.rint(out), 0, 255).astype(np.uint8)
        rng = np.random.default_rng(
            [self.seed, 201, int(timestamp_ns) % (1 << 62), zlib.crc32(cam.channel.encode())]
        )
        sigma = READ_NOISE + SHOT_NOISE * np.sqrt(out)
        out = out + sigma * rng.standard_normal(out.shape, dtype=np.float32)
        return np.clip(np.rint(out), 0, 255).astype(np.uint8)

    def describe(self) -> dict:
        """What the cameras did (JSON-able): per camera its white balance, vignetting strength and the
        exposure gain of every image it took, and the log's :func:`reference_gain`."""
        cams = {ch: {"white_balance": [float(x) for x in self.params[ch]["wb"]],
                     "vignette": float(self.params[ch]["vignette"]),
                     "images": [[ts, g] for ts, g in self.applied[ch]]} for ch in self.params}
        return {"cameras": cams, "reference_gain": [float(x) for x in reference_gain(cams)]}


def reference_gain(cameras: dict) -> np.ndarray:
    """(3,) linear gain per colour channel of the log's mean exposure: the geometric mean over every image
    of its exposure gain times its camera's white balance (vignetting is 1 at the image centre).

    An image compensated to the log's own mean exposure is the truth at this gain (``expose(image, 1 /
    gain)`` brings it to the truth's unit exposure): a single offset per log that no image reveals, since
    the auto-exposure aims at a brightness, not at unit gain.
    """
    logs = [np.log(g) + np.log(np.asarray(c["white_balance"], np.float64))
            for c in cameras.values() for _, g in c["images"]]
    return np.exp(np.mean(logs, axis=0)) if logs else np.ones(3)


def expose(img: np.ndarray, gain_rgb: np.ndarray) -> np.ndarray:
    """The uint8 RGB image ``img`` at ``gain_rgb`` times its exposure (in linear light, clipped as a sensor
    clips), as float32 8-bit values: the truth as a camera at that fixed exposure would see it."""
    return to_display(to_linear(img) * np.asarray(gain_rgb, np.float32)[None, None, :]).astype(np.float32)


def to_linear(img: np.ndarray) -> np.ndarray:
    """uint8 RGB -> float32 linear light in [0, 1] (the cameras' gamma 2.2)."""
    return (img.astype(np.float32) / 255.0) ** GAMMA


def to_display(linear: np.ndarray) -> np.ndarray:
    """Linear light -> 8-bit values (float, unrounded), clipped as a sensor clips: the inverse of
    :func:`to_linear` that :meth:`CameraEffects.apply` and :func:`expose` share."""
    return 255.0 * np.clip(linear, 0.0, 1.0) ** (1.0 / GAMMA)


def log_reference_gain(log_dir: str | Path) -> np.ndarray | None:
    """:func:`reference_gain` of a synthetic log from its ``CAMERA_EFFECTS_FILE``; None for a log whose
    cameras had no exposure effects (its truth is already at the images' exposure)."""
    path = Path(log_dir) / CAMERA_EFFECTS_FILE
    if not path.is_file():
        return None
    return reference_gain(json.loads(path.read_text())["cameras"])
