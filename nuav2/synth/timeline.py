"""Sensor timestamps of a synthetic log, with AV2's rates and phases.

Lidar sweeps at 10 Hz on whole microseconds (with a little period jitter); every camera at
20 Hz with its own phase relative to the sweeps (the av2_format.md table, the worst one
pulled in from -22.5 to -17.5 ms so every sweep keeps an image inside the loader's 25 ms
tolerance) plus sub-microsecond jitter, as in real logs whose camera stamps are not whole us.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SWEEP_PERIOD_NS = 100_000_000
IMAGE_PERIOD_NS = 50_000_000
T_BASE_NS = 315_966_000_000_000_000  # about the GPS-epoch offset of real AV2 stamps
CAMERA_PHASE_NS = {
    "ring_front_center": -10_000_000,
    "ring_front_left": -17_500_000,
    "ring_front_right": 2_500_000,
    "ring_side_left": 12_500_000,
    "ring_side_right": 17_500_000,
    "ring_rear_left": -2_500_000,
    "ring_rear_right": -15_000_000,
    "stereo_front_left": -10_000_000,
    "stereo_front_right": -10_000_000,
}
SWEEP_JITTER_US = 200
IMAGE_JITTER_NS = 400_000


@dataclass(frozen=True, eq=False)
class Timeline:
    sweeps_ns: np.ndarray  # (N,) int64
    images_ns: dict[str, np.ndarray]  # channel -> (2N,) int64; images 2k, 2k+1 belong to sweep k

    @property
    def t0_ns(self) -> int:
        return int(self.sweeps_ns[0])

    def all_sensor_ns(self) -> np.ndarray:
        """Sorted unique timestamps of every sweep and image (the pose table's rows)."""
        return np.unique(np.concatenate([self.sweeps_ns, *self.images_ns.values()]))


def make_timeline(rng: np.random.Generator, n_sweeps: int, channels: list[str]) -> Timeline:
    """Draw the log's timestamps; ``channels`` fixes the order of the per-camera jitter draws."""
    t0 = T_BASE_NS + int(rng.integers(0, 10**9)) * 1000
    jitter = rng.integers(-SWEEP_JITTER_US, SWEEP_JITTER_US + 1, n_sweeps) * 1000
    jitter[0] = 0
    sweeps = t0 + np.arange(n_sweeps, dtype=np.int64) * SWEEP_PERIOD_NS + jitter
    images = {}
    for ch in channels:
        if ch not in CAMERA_PHASE_NS:
            raise ValueError(f"no AV2 camera phase for channel {ch!r}")
        j = np.arange(2 * n_sweeps, dtype=np.int64)
        images[ch] = (t0 + CAMERA_PHASE_NS[ch] + j * IMAGE_PERIOD_NS
                      + rng.integers(-IMAGE_JITTER_NS, IMAGE_JITTER_NS + 1, len(j)))
    return Timeline(sweeps.astype(np.int64), images)
