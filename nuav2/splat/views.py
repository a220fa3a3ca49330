"""Source camera images for reconstruction: which images, their poses at their own timestamps,
their pixels at the training resolution (read lazily, kept as uint8) and their ego-body masks."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numba import njit

from nuav2.exposure import ExposureModel
from nuav2.geometry import F64
from nuav2.image_decode import load_image_u8
from nuav2.rig import CameraSpec
from nuav2.scene import SceneLog


@dataclass
class SourceView:
    """One source camera image at training resolution, its pose and (lazily) its pixels."""

    index: int
    channel: str
    timestamp_ns: int
    path: Path
    cam: CameraSpec  # scaled to the training resolution
    city_T_cam: F64
    valid: np.ndarray = field(repr=False)  # (H, W) bool, False under the ego-body mask
    exposure: ExposureModel | None = field(default=None, repr=False)  # corrects image ``index`` when set
    source_size: tuple[int, int] | None = None  # (width, height) of the file, from the rig: decode smaller
    _image: np.ndarray | None = field(default=None, repr=False)
    _raw: np.ndarray | None = field(default=None, repr=False)  # uncorrected pixels kept for image_u8

    def image_u8(self) -> np.ndarray:
        """(H, W, 3) uint8 RGB at the training resolution (kept in memory: 4x smaller than float), at the
        log's reference exposure once :meth:`set_exposure` has been called."""
        if self._image is None:
            img = self._raw if self._raw is not None else self._decode()
            self._raw = None
            self._image = img if self.exposure is None else self.exposure.correct(img, self.index, self.cam.K)
        return self._image

    def raw_image_u8(self) -> np.ndarray:
        """The image as the camera took it (no exposure correction; cached only until it is corrected)."""
        if self.exposure is None:
            return self.image_u8()
        return self._raw if self._raw is not None else self._decode()

    def set_exposure(self, model: ExposureModel | None) -> None:
        """Correct this image (``index``) with ``model`` from now on. Pixels read uncorrected (the
        exposure solve reads every image) are kept and corrected, not decoded a second time."""
        if self.exposure is None and self._image is not None:
            self._raw = self._image
        self.exposure = model
        self._image = None

    def _decode(self) -> np.ndarray:
        return load_image_u8(self.path, self.cam.width, self.cam.height, self.source_size)

    def image(self) -> np.ndarray:
        """(H, W, 3) float32 RGB in [0, 1] at the training resolution."""
        img = self.image_u8()
        return img.astype(np.float32) / 255.0 if img.dtype == np.uint8 else img.astype(np.float32)


def load_image(path: Path, width: int, height: int) -> np.ndarray:
    """Read an image file as float32 RGB [0,1], area-resized to width x height."""
    return load_image_u8(path, width, height).astype(np.float32) / 255.0


def source_views(scene: SceneLog, image_scale: float, *, frame_stride: int = 1,
                 channels: list[str] | None = None) -> list[SourceView]:
    """Every ``frame_stride``-th image of every camera, posed at its own timestamp."""
    views: list[SourceView] = []
    for cam in scene.rig.cameras:
        if channels is not None and cam.channel not in channels:
            continue
        small = cam.scaled(image_scale)
        valid = ~small.ego_mask()
        frames = sorted(scene.camera_frames.get(cam.channel, []), key=lambda f: f.timestamp_ns)
        for f in frames[::frame_stride]:
            city_T_cam = scene.city_T_ego_at(int(f.timestamp_ns)) @ cam.ego_T_cam
            views.append(SourceView(len(views), cam.channel, int(f.timestamp_ns), Path(f.path), small,
                                    city_T_cam, valid, source_size=(cam.width, cam.height)))
    return views


@dataclass
class Projection:
    """Pixels of points in one view: index into the input, pixel coordinates, camera depth."""

    idx: np.ndarray
    u: F64
    v: F64
    z: F64


def project(points_scene: F64, cam: CameraSpec, cam_T_scene: F64, near: float = 0.1) -> Projection:
    """Points in front of the camera that land inside the image (rig pixel convention); NaN points
    never land. One compiled pass: seeding projects every seed into every source image (on a 15 s log
    about 1,000 images x 300k seeds; numpy's temporaries made that 40 s)."""
    pts = np.ascontiguousarray(points_scene, dtype=np.float64).reshape(-1, 3)
    T = np.ascontiguousarray(cam_T_scene, dtype=np.float64)
    K = np.asarray(cam.K, np.float64)
    idx, u, v, z = _project_kernel(pts, T, float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]),
                                   float(cam.width), float(cam.height), float(near))
    return Projection(idx, u, v, z)


@njit(cache=True, nogil=True)
def _project_kernel(pts, T, fx, fy, cx, cy, width, height, near):  # pragma: no cover - compiled
    n = pts.shape[0]
    idx = np.empty(n, np.int64)
    u_out = np.empty(n)
    v_out = np.empty(n)
    z_out = np.empty(n)
    m = 0
    for i in range(n):
        x, y, w = pts[i, 0], pts[i, 1], pts[i, 2]
        pz = x * T[2, 0] + y * T[2, 1] + w * T[2, 2] + T[2, 3]
        if not pz > near:
            continue
        px = x * T[0, 0] + y * T[0, 1] + w * T[0, 2] + T[0, 3]
        py = x * T[1, 0] + y * T[1, 1] + w * T[1, 2] + T[1, 3]
        u = fx * px / pz + cx
        v = fy * py / pz + cy
        if u > -0.5 and u < width - 0.5 and v > -0.5 and v < height - 0.5:
            idx[m] = i
            u_out[m] = u
            v_out[m] = v
            z_out[m] = pz
            m += 1
    return idx[:m].copy(), u_out[:m].copy(), v_out[:m].copy(), z_out[:m].copy()


def bilinear(image: np.ndarray, u: F64, v: F64) -> np.ndarray:
    """Bilinear sample of an (H, W, C) image at rig-convention pixel coordinates (centre of u is u)."""
    h, w = image.shape[:2]
    u = np.clip(u, 0, w - 1)
    v = np.clip(v, 0, h - 1)
    u0 = np.minimum(np.floor(u).astype(np.int64), w - 2 if w > 1 else 0)
    v0 = np.minimum(np.floor(v).astype(np.int64), h - 2 if h > 1 else 0)
    u1, v1 = np.minimum(u0 + 1, w - 1), np.minimum(v0 + 1, h - 1)
    a, b = (u - u0)[:, None], (v - v0)[:, None]
    return ((1 - a) * (1 - b) * image[v0, u0] + a * (1 - b) * image[v0, u1]
            + (1 - a) * b * image[v1, u0] + a * b * image[v1, u1])
