"""SynthConfig: every knob of the synthetic world and log, validated, JSON round-trippable.

The defaults make a CI-sized log (2 s of driving, 1/8-resolution cameras, ~30k lidar points
per sweep); benchmarks raise ``seconds``, ``image_scale`` and ``lidar_azimuth_steps``.

Realism is a ladder of presets (``PRESETS``): ``easy`` is the original world (flat ground, one
intersection, box actors, fixed light, ideal sensors and labels), ``medium`` breaks the
geometric assumptions (relief, varied layouts and ego manoeuvres, content that is not its box,
noisy lidar and labels) and ``hard`` also the photometric ones (cast shadows and a structured
sky, per-camera exposure / white balance / vignetting / noise). Each realism factor is one
boolean field (``FACTORS``); ``None`` takes the preset's value, so an ablation is a loop:
``SynthConfig.for_preset("easy", relief=True)``.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

from av2.geometry.utm import CityName

PRESETS = ("easy", "medium", "hard")
# AV2 ring cameras are 2048 px on the long side: 8x makes 16,384 px, the converter's largest image side.
MAX_IMAGE_SCALE = 8.0
# One switch per realism factor, in the order the ablation adds them.
FACTORS = ("relief", "layouts", "content", "shadows", "exposure", "lidar_noise", "label_noise")
PRESET_FACTORS = {
    "easy": frozenset(),
    "medium": frozenset({"relief", "layouts", "content", "lidar_noise", "label_noise"}),
    "hard": frozenset(FACTORS),
}
LAYOUTS = ("four_way", "arterial", "t_junction", "curved", "y_junction")
# Fields of the original (easy-only) config: always serialised. Later fields are serialised only
# when they differ from what the preset implies, so an easy config's dict (and with it the log id
# and every byte of the log) is what it was before the presets existed.
_LEGACY_FIELDS = ("seconds", "image_scale", "lidar_azimuth_steps", "lidar_max_range_m", "n_parked",
                  "n_moving", "n_pedestrians", "ego_speed_mps", "lane_change", "include_stereo",
                  "texture_res_m", "map_margin_m", "city", "jpeg_quality")


@dataclass(frozen=True)
class SynthConfig:
    """Size, content and realism of one synthetic AV2 log (the seed draws the rest)."""

    seconds: float = 2.0  # driving time; one lidar sweep per 0.1 s
    image_scale: float = 0.125  # AV2 camera resolution factor (0.125 -> 256x194)
    lidar_azimuth_steps: int = 512  # rays per beam per sweep (64 beams -> 32768 rays)
    lidar_max_range_m: float = 150.0
    n_parked: int = 6
    n_moving: int = 3
    n_pedestrians: int = 1
    ego_speed_mps: float | None = None  # None: drawn from the seed (easy: [8, 10]; layouts: cruise [7, 13])
    lane_change: bool = True  # ego drifts from the inner to the outer lane (gentle, 5 s manoeuvre)
    include_stereo: bool = False  # also write the two stereo_front cameras
    texture_res_m: float = 0.05  # metres per pixel of the ground (BEV) texture
    map_margin_m: float = 60.0  # map and world extend this far beyond the ego path
    city: str = "PIT"
    jpeg_quality: int = 92
    preset: str = "easy"  # the rung the factor switches default to
    layout: str | None = None  # road layout (LAYOUTS); None: four_way, or drawn from the seed with `layouts`
    relief: bool | None = None  # terrain with grades, crests, sags, cross-fall (ego pitches and rolls)
    layouts: bool | None = None  # layouts drawn from the seed; ego turns, changes lanes, stops and starts
    content: bool | None = None  # shaped vehicles of several classes, walking pedestrians, cyclists,
    #                              street furniture, trees, kerb steps, varied facades
    shadows: bool | None = None  # sun with cast shadows, sky with sun glow and clouds
    exposure: bool | None = None  # log cameras: drifting auto-exposure, white balance, vignetting, noise
    lidar_noise: bool | None = None  # range noise, grazing / dark-surface dropouts
    label_noise: bool | None = None  # per-track offsets, per-frame jitter, size errors, missed far objects
    n_cyclists: int = 2  # cyclists (with `content`)
    camera_noise: bool = True  # with `exposure`: read/shot noise, JPEG quality 85 (False: the gains alone)

    def __post_init__(self) -> None:
        def bad(name: str, why: str) -> ValueError:
            return ValueError(f"SynthConfig.{name} {why}, got {getattr(self, name)!r}")

        for name in ("seconds", "image_scale", "lidar_max_range_m", "texture_res_m", "map_margin_m"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise bad(name, "must be a finite number > 0")
        if round(self.seconds * 10) < 1:
            raise bad("seconds", "must give at least one 10 Hz sweep (> 0.05)")
        if self.image_scale > MAX_IMAGE_SCALE:
            raise bad("image_scale", f"must be <= {MAX_IMAGE_SCALE:g} (AV2's 2048 px camera side at most "
                                     f"{2048 * MAX_IMAGE_SCALE:.0f} px)")
        for name in ("n_parked", "n_moving", "n_pedestrians", "n_cyclists"):
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
        if not isinstance(self.camera_noise, bool):
            raise bad("camera_noise", "must be a bool")
        if self.preset not in PRESETS:
            raise bad("preset", f"must be one of {PRESETS}")
        if self.layout is not None and self.layout not in LAYOUTS:
            raise bad("layout", f"must be None or one of {LAYOUTS}")
        for name in FACTORS:
            v = getattr(self, name)
            if v is None:  # resolve from the preset; the dataclass stays frozen for everyone else
                object.__setattr__(self, name, name in PRESET_FACTORS[self.preset])
            elif not isinstance(v, bool):
                raise bad(name, "must be None or a bool")

    @classmethod
    def for_preset(cls, name: str, **overrides) -> SynthConfig:
        """The config of preset ``name`` (``PRESETS``), with any field overridden.

        Use this (not ``dataclasses.replace(cfg, preset=...)``) to change preset: a built config's
        factor fields are already resolved, so replacing ``preset`` alone keeps the old factors."""
        if name not in PRESETS:
            raise ValueError(f"preset must be one of {PRESETS}, got {name!r}")
        return cls(preset=name, **overrides)

    @property
    def factors(self) -> frozenset[str]:
        """The realism factors switched on."""
        return frozenset(f for f in FACTORS if getattr(self, f))

    @property
    def n_sweeps(self) -> int:
        return int(round(self.seconds * 10))

    def to_dict(self) -> dict:
        """Legacy fields always; newer ones only where they differ from the preset's implied value."""
        d = asdict(self)
        implied = {f.name: f.default for f in fields(self)}
        implied.update({f: f in PRESET_FACTORS[self.preset] for f in FACTORS})
        return {k: v for k, v in d.items() if k in _LEGACY_FIELDS or v != implied[k]}

    @staticmethod
    def from_dict(d: dict, src: str = "<dict>") -> SynthConfig:
        """Inverse of :meth:`to_dict`; unknown keys are an error naming ``src``."""
        known = {f.name for f in fields(SynthConfig)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise ValueError(f"{src}: unknown SynthConfig field(s) {unknown}")
        return SynthConfig(**d)
