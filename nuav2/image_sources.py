"""Which cameras and images a conversion writes, per mode: the one switch between native,
warp and render mode. The writer, tables, LIDAR_TOP and maps are the same in all three.

- native: the log's own cameras (re-expressed in the ground-level output ego frame) and images.
- warp / render: the target rig's cameras (``--rig``, ``--scale``), one image per camera at
  each sample, produced by the depth-warp renderer or the Gaussian-splat reconstruction.
- truth (synthetic logs only): the target rig's cameras, rendered exactly from the log's saved
  world by the ground-truth renderer (:mod:`nuav2.truth_images`).

Re-rendered images also get a confidence (covered fraction / coverage of source views),
recorded per image file so users can drop weak frames (``nuav2_image_quality.json``).
"""

from __future__ import annotations

import contextlib
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nuav2.atomic import atomic_write_json
from nuav2.conversion_modes import MODES
from nuav2.geometry import F64
from nuav2.nuscenes_db.images import (
    CameraShot,
    ImageSource,
    NativeImages,
    RenderedImages,
    images_at_once_of,
    storing_of,
)
from nuav2.nuscenes_db.writer import output_rig_native
from nuav2.rig import CameraSpec, Rig, load_rig
from nuav2.scene import SceneLog

QUALITY_FILE = "nuav2_image_quality.json"


def output_rig_target(rig: str, scale: float) -> Rig:
    """The target rig in the ground-level output ego frame, at ``scale`` times its resolution."""
    return load_rig(rig, scale).with_origin_height(0.0)


@dataclass
class QualityRecordingImages:
    """Wraps a :class:`RenderedImages` whose renderer keeps ``coverage[channel][timestamp_ns]``
    and records that confidence per written file (relative to the dataroot)."""

    inner: RenderedImages  # or any source with the same methods and a ``render.coverage`` dict
    dataroot: Path
    by_file: dict[str, float] = field(default_factory=dict)

    def shots(self, scene: SceneLog, out_rig: Rig, sample_ns: np.ndarray) -> dict[str, list[CameraShot]]:
        return self.inner.shots(scene, out_rig, sample_ns)

    def extension(self, shot: CameraShot) -> str:
        return self.inner.extension(shot)

    def store(self, shot: CameraShot, camera: CameraSpec, city_T_cam: F64, dst: Path) -> None:
        self.inner.store(shot, camera, city_T_cam, dst)
        coverage = getattr(self.inner.render, "coverage", {})
        conf = coverage.get(shot.channel, {}).get(int(shot.timestamp_ns))
        if conf is not None:
            self.by_file[Path(dst).resolve().relative_to(self.dataroot.resolve()).as_posix()] = float(conf)

    def fingerprint(self) -> str:
        return self.inner.fingerprint()

    @property
    def images_at_once(self) -> int:
        return images_at_once_of(self.inner)

    def storing(self) -> contextlib.AbstractContextManager:
        return storing_of(self.inner)

    @property
    def device(self) -> str | None:
        """The torch device the inner source rendered on (render mode), else None."""
        return getattr(self.inner, "device", None)


def image_source_for(scene: SceneLog, mode: str, dataroot: Path, *, image_link: str = "copy",
                     rig: str = "nuscenes", scale: float = 1.0,
                     recon_preset: str = "default", min_confidence: float = 0.0,
                     progress: bool = False, device: str = "auto",
                     threads: int = 1) -> tuple[Rig, ImageSource]:
    """Output rig and image source of one log for ``mode`` (``progress``: report reconstruction progress;
    ``device``: where render mode reconstructs and renders, :mod:`nuav2.splat.device`; ``threads``: warp
    mode's threads)."""
    if mode == "native":
        return output_rig_native(scene), NativeImages(image_link)
    out_rig = output_rig_target(rig, scale)
    if mode == "warp":
        from nuav2.warp.provider import warp_image_source

        return out_rig, QualityRecordingImages(warp_image_source(scene, threads=threads), Path(dataroot))
    if mode == "render":
        from nuav2.recon import render_image_source

        # Checkpoints beside the dataroot let a killed render-mode conversion resume training.
        ckpt = Path(dataroot) / ".recon" / scene.log_id
        source = render_image_source(scene, out_rig, preset=recon_preset, min_confidence=min_confidence,
                                     checkpoint_dir=ckpt, progress=progress, device=device)
        return out_rig, QualityRecordingImages(source, Path(dataroot))
    if mode == "truth":
        from nuav2.truth_images import truth_image_source

        return out_rig, truth_image_source(scene)
    raise ValueError(f"mode must be one of {MODES}, got {mode!r}")


def write_quality_table(dataroot: Path, version: str, per_file: dict[str, float]) -> Path | None:
    """``<version>/nuav2_image_quality.json``: {sample_data token: confidence} for re-rendered images."""
    if not per_file:
        return None
    records = json.loads((Path(dataroot) / version / "sample_data.json").read_text())
    out = {r["token"]: per_file[r["filename"]] for r in records if r["filename"] in per_file}
    path = Path(dataroot) / version / QUALITY_FILE
    atomic_write_json(path, dict(sorted(out.items())), indent=1)
    return path
