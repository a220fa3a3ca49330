"""Rendering a reconstruction in a target rig, and the camera-image provider for the nuScenes writer.

Frame alignment is the paper's eq. 1-2: the target vehicle rides the source vehicle's pose,
``city_T_egoT = city_T_egoS(t) @ egoS_T_egoT`` (the two vehicle frames differ in origin height
only), and each target camera sits at ``city_T_camT = city_T_egoT @ egoT_T_camT``. The writer
(nuav2/nuscenes_db/images.py) computes exactly these poses and calls a ``RenderFn``
``(channel, camera, city_T_cam, timestamp_ns) -> uint8 (H, W, 3)``; :class:`SplatRenderer` is
one, and records each image's quality (:mod:`nuav2.splat.quality`) as it goes.
:class:`SplatImageSource` wraps it as a writer ``ImageSource`` that can leave out the sample
times where any camera's confidence is below ``min_confidence``.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from nuav2.geometry import F64, egoS_T_egoT_from_heights
from nuav2.rig import CameraSpec, Rig
from nuav2.scene import SceneLog
from nuav2.splat.quality import ImageQuality, QualityConfig, SourceCoverage, image_quality
from nuav2.splat.scene_model import SplatScene


def target_city_T_cams(scene: SceneLog, target_rig: Rig, timestamp_ns: int) -> dict[str, F64]:
    """Each target camera's city pose when the target vehicle rides the source ego at ``timestamp_ns``."""
    egoS_T_egoT = egoS_T_egoT_from_heights(scene.rig.origin_height_m, target_rig.origin_height_m)
    city_T_egoT = scene.city_T_ego_at(int(timestamp_ns)) @ egoS_T_egoT
    return {cam.channel: city_T_egoT @ cam.ego_T_cam for cam in target_rig.cameras}


def to_uint8(rgb: torch.Tensor) -> np.ndarray:
    """[0,1] float image -> uint8, rounded; NaN (never expected) becomes 0."""
    arr = torch.nan_to_num(rgb.detach(), nan=0.0).clamp(0, 1).cpu().numpy()
    return (arr * 255.0 + 0.5).astype(np.uint8)


def sample_data_key(channel: str, timestamp_ns: int) -> str:
    """Key of one rendered image in ``SplatRenderer.records``: ``channel@timestamp_ns``."""
    return f"{channel}@{int(timestamp_ns)}"


@dataclass
class SplatRenderer:
    """A writer ``RenderFn`` over a reconstruction. With a ``source_coverage`` model it scores
    every image it renders: ``coverage[channel][timestamp_ns]`` is the confidence (the same
    shape the warp renderer exposes, read by the convert pipeline's quality table) and
    ``records`` keeps the full :class:`ImageQuality` by ``channel@timestamp_ns``."""

    splat: SplatScene
    source_coverage: SourceCoverage | None = None
    quality_cfg: QualityConfig = field(default_factory=QualityConfig)
    coverage: dict[str, dict[int, float]] = field(default_factory=dict)
    records: dict[str, dict] = field(default_factory=dict)

    def render(self, camera: CameraSpec, city_T_cam: F64, timestamp_ns: int):
        with torch.no_grad():
            return self.splat.render(camera, np.asarray(city_T_cam, np.float64), int(timestamp_ns))

    def quality(self, camera: CameraSpec, city_T_cam: F64, out, timestamp_ns: int) -> ImageQuality | None:
        if self.source_coverage is None:
            return None
        scene_T_cam = self.splat.scene_T_city @ np.asarray(city_T_cam, np.float64)
        boxes = nonrigid_boxes_at(self.splat, timestamp_ns)
        return image_quality(out.depth.cpu().numpy(), out.alpha.cpu().numpy(), camera, scene_T_cam,
                             self.source_coverage, self.quality_cfg, boxes)

    def __call__(self, channel: str, camera: CameraSpec, city_T_cam: F64, timestamp_ns: int) -> np.ndarray:
        out = self.render(camera, city_T_cam, timestamp_ns)
        q = self.quality(camera, city_T_cam, out, timestamp_ns)
        if q is not None:
            self.coverage.setdefault(channel, {})[int(timestamp_ns)] = q.confidence
            self.records[sample_data_key(channel, timestamp_ns)] = {
                "channel": channel, "timestamp_ns": int(timestamp_ns), **q.to_dict()}
        return to_uint8(out.rgb)

    def confidence(self, camera: CameraSpec, city_T_cam: F64, timestamp_ns: int,
                   scale: float = 0.25) -> float:
        """Cheap confidence estimate from a low-resolution render (1.0 without a coverage model)."""
        if self.source_coverage is None:
            return 1.0
        small = camera.scaled(scale)
        out = self.render(small, city_T_cam, timestamp_ns)
        q = self.quality(small, city_T_cam, out, timestamp_ns)
        return 1.0 if q is None else q.confidence


def nonrigid_boxes_at(splat: SplatScene, timestamp_ns: int) -> tuple[F64, F64]:
    """(scene_T_box (B, 4, 4), sizes (B, 3)) of the modelled non-rigid actors present at a time."""
    from nuav2.actor_tracks import is_non_rigid

    tracks = [o.track for o in splat.objects
              if is_non_rigid(o.track.category) and o.track.present(timestamp_ns)]
    if not tracks:
        return np.zeros((0, 4, 4)), np.zeros((0, 3))
    return (np.stack([t.scene_T_box_at(int(timestamp_ns)) for t in tracks]),
            np.stack([np.asarray(t.size_lwh, np.float64) for t in tracks]))


def scene_fingerprint(splat: SplatScene) -> str:
    """Short hash of the reconstruction's parameters (a changed scene re-renders its shards)."""
    h = hashlib.sha256()
    for g in [splat.background] + [o.gaussians for o in splat.objects]:
        for t in g.tensors().values():
            h.update(t.detach().cpu().contiguous().numpy().tobytes())
    h.update(splat.sky.texture.detach().cpu().numpy().tobytes())
    return h.hexdigest()[:16]


@dataclass
class SplatImageSource:
    """Writer ``ImageSource`` rendering every output camera at each sample time from a reconstruction.

    With ``min_confidence`` > 0, ``shots`` first estimates every camera's confidence at each
    candidate time (low-resolution render) and leaves out times where any camera falls below
    it, so those samples never enter the database; ``dropped`` lists them.
    """

    render: SplatRenderer
    min_confidence: float = 0.0
    at_sweeps: bool = False
    jpeg_quality: int = 95
    estimate_scale: float = 0.25
    dropped: list[dict] = field(default_factory=list)
    _cache: dict = field(default_factory=dict, repr=False)  # (channel, t, w, h) -> estimated confidence
    _rendered: object = field(default=None, repr=False)

    @property
    def renderer(self) -> SplatRenderer:
        return self.render

    @property
    def device(self) -> str:
        """Where the reconstruction trained and renders (``cpu`` or ``cuda:N``), for the convert report."""
        return str(self.render.splat.info.get("device") or self.render.splat.device)

    def _images(self):
        from nuav2.nuscenes_db.images import RenderedImages

        if self._rendered is None:
            name = f"splat-{scene_fingerprint(self.render.splat)}"
            self._rendered = RenderedImages(self.render, name=name, at_sweeps=self.at_sweeps,
                                            jpeg_quality=self.jpeg_quality)
        return self._rendered

    def shots(self, scene: SceneLog, out_rig: Rig, sample_ns: np.ndarray) -> dict:
        shots = self._images().shots(scene, out_rig, sample_ns)
        if self.min_confidence <= 0:
            return shots
        times = sorted({s.timestamp_ns for lst in shots.values() for s in lst})
        bad = set()
        for t in times:
            poses = target_city_T_cams(scene, out_rig, t)
            for cam in out_rig.cameras:
                key = (cam.channel, t, cam.width, cam.height)
                if key not in self._cache:
                    self._cache[key] = self.render.confidence(cam, poses[cam.channel], t,
                                                              self.estimate_scale)
                if self._cache[key] < self.min_confidence:
                    bad.add(t)
                    self.dropped.append({"channel": cam.channel, "timestamp_ns": int(t),
                                         "confidence": float(self._cache[key])})
        if times and len(bad) == len(times):  # else the writer blames the cameras' sync
            best = max(min(self._cache[(c.channel, t, c.width, c.height)] for c in out_rig.cameras)
                       for t in times)
            raise ValueError(f"--min-confidence {self.min_confidence:g} leaves out all {len(times)} sample "
                             f"times: at each one some target camera is below it (the best time's "
                             f"weakest camera: {best:.3f}); lower it to keep samples")
        return {ch: [s for s in lst if s.timestamp_ns not in bad] for ch, lst in shots.items()}

    def extension(self, shot) -> str:
        return ".jpg"

    def store(self, shot, camera: CameraSpec, city_T_cam: F64, dst: Path) -> None:
        self._images().store(shot, camera, city_T_cam, dst)

    def fingerprint(self) -> str:
        return f"{self._images().fingerprint()}:minconf={self.min_confidence}"
