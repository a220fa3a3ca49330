"""What a real camera does to the clean render, for the images written into the AV2 log only.

With the ``exposure`` factor each ring camera has its own auto-exposure that chases a target
brightness with a lag and drifts over seconds, its own white balance, lens vignetting, and
sensor noise (read noise plus shot noise), and the JPEGs are more compressed (``camera_noise=False``
in the config keeps the gains and drops the noise and the extra compression, to tell their costs
apart). The ground-truth renderer (render.py) never applies any of this: the truth is unit
exposure, neutral white balance, no vignetting, no noise.
"""

from __future__ import annotations

import zlib

import numpy as np

from nuav2.rig import CameraSpec

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
        linear = (img.astype(np.float32) / 255.0) ** GAMMA
        valid = ~cam.ego_mask() if cam.ego_mask_polygons else np.ones(img.shape[:2], bool)
        gain = self.gain_for(cam.channel, linear, valid, t_s)
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
        out = linear * (gain * vig)[..., None] * p["wb"][None, None, :].astype(np.float32)
        out = 255.0 * np.clip(out, 0.0, 1.0) ** (1.0 / GAMMA)
        if not self.noise:
            return np.clip(np.rint(out), 0, 255).astype(np.uint8)
        rng = np.random.default_rng(
            [self.seed, 201, int(timestamp_ns) % (1 << 62), zlib.crc32(cam.channel.encode())]
        )
        sigma = READ_NOISE + SHOT_NOISE * np.sqrt(out)
        out = out + sigma * rng.standard_normal(out.shape, dtype=np.float32)
        return np.clip(np.rint(out), 0, 255).astype(np.uint8)
