"""SynthConfig: every knob of the synthetic world and log, validated, JSON round-trippable.

The defaults make a CI-sized log (2 s of driving, 1/8-resolution cameras, ~30k lidar points
per sweep); benchmarks raise ``seconds``, ``image_scale`` and ``lidar_azimuth_steps``.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

from av2.geometry.utm import CityName


@dataclass(frozen=True)
class SynthConfig:
    """Size and content of one synthetic AV2 log (the seed picks the layout, this picks the scale)."""

    seconds: float = 2.0  # driving time; one lidar sweep per 0.1 s
    image_scale: float = 0.125  # AV2 camera resolution factor (0.125 -> 256x194)
    lidar_azimuth_steps: int = 512  # rays per beam per sweep (64 beams -> 32768 rays)
    lidar_max_range_m: float = 150.0
    n_parked: int = 6
    n_moving: int = 3
    n_pedestrians: int = 1
    ego_speed_mps: float | None = None  # None: drawn from the seed in [8, 10]
    lane_change: bool = True  # ego drifts from the inner to the outer lane (gentle, 5 s manoeuvre)
    include_stereo: bool = False  # also write the two stereo_front cameras
    texture_res_m: float = 0.05  # metres per pixel of the ground (BEV) texture
    map_margin_m: float = 60.0  # map and world extend this far beyond the ego path
    city: str = "PIT"
    jpeg_quality: int = 92

    def __post_init__(self) -> None:
        def bad(name: str, why: str) -> ValueError:
            return ValueError(f"SynthConfig.{name} {why}, got {getattr(self, name)!r}")

        for name in ("seconds", "image_scale", "lidar_max_range_m", "texture_res_m", "map_margin_m"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise bad(name, "must be a finite number > 0")
        if round(self.seconds * 10) < 1:
            raise bad("seconds", "must give at least one 10 Hz sweep (>= 0.05)")
        for name in ("n_parked", "n_moving", "n_pedestrians"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 0:
                raise bad(name, "must be an integer >= 0")
        if not isinstance(self.lidar_azimuth_steps, int) or self.lidar_azimuth_steps < 8:
            raise bad("lidar_azimuth_steps", "must be an integer >= 8")
        if self.ego_speed_mps is not None and not (0.5 <= float(self.ego_speed_mps) <= 30.0):
            raise bad("ego_speed_mps", "must be None or within [0.5, 30] m/s")
        if not 0.005 <= self.texture_res_m <= 0.5:
            raise bad("texture_res_m", "must be within [0.005, 0.5] m/px")
        if self.city not in {c.value for c in CityName}:
            raise bad("city", f"must be an AV2 city code {[c.value for c in CityName]}")
        if not isinstance(self.jpeg_quality, int) or not 1 <= self.jpeg_quality <= 100:
            raise bad("jpeg_quality", "must be an integer in [1, 100]")

    @property
    def n_sweeps(self) -> int:
        return int(round(self.seconds * 10))

    def to_dict(self) -> dict:
        return asdict(self)

    @staticmethod
    def from_dict(d: dict, src: str = "<dict>") -> SynthConfig:
        """Inverse of :meth:`to_dict`; unknown keys are an error naming ``src``."""
        known = {f.name for f in fields(SynthConfig)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise ValueError(f"{src}: unknown SynthConfig field(s) {unknown}")
        return SynthConfig(**d)
