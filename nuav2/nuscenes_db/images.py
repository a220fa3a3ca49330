"""Where a database's camera images come from: the one piece native and render mode swap.

The writer asks an :class:`ImageSource` which images each output camera has (``shots``),
works out every image's pose and sample, and then asks the source to store each image
(``store``), handing it the camera's pose in the city frame at that time:
``city_T_camT = city_T_egoS(t) @ egoS_T_egoT @ egoT_T_camT``.

- :class:`NativeImages` (native mode): the source's own images at their own timestamps,
  copied, hard-linked or symlinked.
- :class:`RenderedImages` (render / warp mode): one image per output camera at each sample
  time (optionally at every sweep time too), produced by a :data:`RenderFn`.
"""

from __future__ import annotations

import contextlib
import os
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Literal, Protocol

import numpy as np

from nuav2.atomic import atomic_write_bytes
from nuav2.geometry import F64
from nuav2.rig import CameraSpec, Rig
from nuav2.scene import SceneLog

ImageLink = Literal["copy", "hardlink", "symlink"]
IMAGE_LINKS: tuple[str, ...] = ("copy", "hardlink", "symlink")

# (channel, camera spec, city_T_cam, timestamp_ns) -> uint8 (H, W, 3) RGB image at the spec's size.
RenderFn = Callable[[str, CameraSpec, F64, int], np.ndarray]


def images_at_once_of(source: object) -> int:
    """Images ``source`` may store at once (its optional ``images_at_once``; 1 when it has none)."""
    return int(getattr(source, "images_at_once", 1))


def storing_of(source: object) -> contextlib.AbstractContextManager:
    """``source``'s optional context around the writer's whole image loop (a null context if none)."""
    return getattr(source, "storing", contextlib.nullcontext)()


class ImageSourceError(ValueError):
    """An image is missing, unreadable or has the wrong size; the message names the file."""


@dataclass(frozen=True)
class CameraShot:
    """One image to write: its channel, capture time and (native mode) the source file."""

    channel: str
    timestamp_ns: int
    source: Path | None = None


class ImageSource(Protocol):
    """What the writer needs from a camera-image provider."""

    def shots(self, scene: SceneLog, out_rig: Rig, sample_ns: np.ndarray) -> dict[str, list[CameraShot]]:
        """Per output camera channel, the images to write, strictly increasing in time.

        ``sample_ns`` are the times samples may sit at: the writer asks once with every sweep
        time (to find which sweeps have all cameras) and once with the chosen samples. A
        renderer returns one image per camera at each; a recorded source ignores them.
        """
        ...

    def extension(self, shot: CameraShot) -> str:
        """File extension (with dot) of the stored image, e.g. ``.jpg``."""
        ...

    def store(self, shot: CameraShot, camera: CameraSpec, city_T_cam: F64, dst: Path) -> None:
        """Put the image at ``dst`` (atomically; ``dst``'s directory exists)."""
        ...

    def fingerprint(self) -> str:
        """What produced the images; a shard written under another fingerprint is redone."""
        ...


def _link_or_copy(src: Path, dst: Path, how: str) -> None:
    """Place ``src`` at ``dst`` by copy / hard link / absolute symlink, replacing ``dst`` atomically."""
    tmp = dst.with_name(f".{dst.name}.{os.getpid()}.tmp")
    if tmp.exists() or tmp.is_symlink():
        tmp.unlink()
    try:
        if how == "copy":
            shutil.copyfile(src, tmp)
        elif how == "hardlink":
            try:
                os.link(src, tmp)
            except OSError as e:
                raise ImageSourceError(f"{src}: cannot hard-link into {dst.parent} ({e}); "
                                       "use --image-link copy or symlink across file systems") from e
        elif how == "symlink":
            os.symlink(src.resolve(), tmp)
        else:
            raise ValueError(f"image link mode must be one of {IMAGE_LINKS}, got {how!r}")
        os.replace(tmp, dst)
    except BaseException:
        if tmp.exists() or tmp.is_symlink():
            tmp.unlink()
        raise


def decode_problem(path: Path) -> str | None:
    """What stops the image at ``path`` from decoding to its end (a truncated JPEG, ...), or None.

    A JPEG is decoded at 1/8 scale (libjpeg's DCT scaling, ~3 ms for a 2048x1550 AV2 image):
    that still reads every entropy-coded byte, so a file cut short fails as it does at full size.
    """
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            im.draft("RGB", (max(1, im.size[0] // 8), max(1, im.size[1] // 8)))
            im.load()
    except (OSError, UnidentifiedImageError, SyntaxError, ValueError) as e:
        return f"does not decode ({e})"
    return None


def image_size(path: Path) -> tuple[int, int]:
    """(width, height) from the file header; raises ImageSourceError naming an unreadable file."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            return im.size
    except (OSError, UnidentifiedImageError) as e:
        raise ImageSourceError(f"{path}: not a readable image ({e})") from e


@dataclass(frozen=True)
class NativeImages:
    """The source log's own images (AV2 native mode)."""

    link: str = "copy"
    check_size: bool = True

    def __post_init__(self) -> None:
        if self.link not in IMAGE_LINKS:
            raise ValueError(f"image link mode must be one of {IMAGE_LINKS}, got {self.link!r}")

    def shots(self, scene: SceneLog, out_rig: Rig, sample_ns: np.ndarray) -> dict[str, list[CameraShot]]:
        out: dict[str, list[CameraShot]] = {}
        for cam in out_rig.cameras:
            frames = sorted(scene.camera_frames.get(cam.channel, []), key=lambda f: f.timestamp_ns)
            if frames:
                out[cam.channel] = [CameraShot(cam.channel, int(f.timestamp_ns), Path(f.path))
                                    for f in frames]
        return out

    def extension(self, shot: CameraShot) -> str:
        assert shot.source is not None
        return shot.source.suffix.lower() or ".jpg"

    def store(self, shot: CameraShot, camera: CameraSpec, city_T_cam: F64, dst: Path) -> None:
        src = shot.source
        if src is None or not src.is_file():
            raise ImageSourceError(f"{src}: image of {shot.channel} at {shot.timestamp_ns} ns is missing")
        if self.check_size:
            size = image_size(src)
            if size != (camera.width, camera.height):
                raise ImageSourceError(f"{src}: image is {size[0]}x{size[1]} but the calibration of "
                                       f"{shot.channel} says {camera.width}x{camera.height}")
        problem = decode_problem(src)  # a dataset must not ship an image its loaders cannot read
        if problem:
            raise ImageSourceError(f"{src}: image of {shot.channel} at {shot.timestamp_ns} ns {problem}")
        _link_or_copy(src, dst, self.link)

    def fingerprint(self) -> str:
        return f"native:{self.link}"


@dataclass(frozen=True)
class RenderedImages:
    """Images produced by ``render`` for each output camera at each sample (and optionally sweep) time."""

    render: RenderFn
    name: str = "render"  # identifies the renderer in the shard fingerprint
    at_sweeps: bool = False
    jpeg_quality: int = 95

    def shots(self, scene: SceneLog, out_rig: Rig, sample_ns: np.ndarray) -> dict[str, list[CameraShot]]:
        times = scene.sweep_timestamps_ns if self.at_sweeps else np.asarray(sample_ns, dtype=np.int64)
        return {cam.channel: [CameraShot(cam.channel, int(t)) for t in times] for cam in out_rig.cameras}

    def extension(self, shot: CameraShot) -> str:
        return ".jpg"

    def store(self, shot: CameraShot, camera: CameraSpec, city_T_cam: F64, dst: Path) -> None:
        import cv2

        img = np.asarray(self.render(shot.channel, camera, city_T_cam, shot.timestamp_ns))
        if img.dtype != np.uint8 or img.shape != (camera.height, camera.width, 3):
            raise ImageSourceError(f"{dst}: renderer returned {img.dtype} {img.shape} for {shot.channel}, "
                                   f"expected uint8 {(camera.height, camera.width, 3)}")
        bgr = cv2.cvtColor(np.ascontiguousarray(img), cv2.COLOR_RGB2BGR)  # 50-90x faster than a flipped copy
        ok, buf = cv2.imencode(".jpg", bgr,
                               [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality])
        if not ok:
            raise ImageSourceError(f"{dst}: JPEG encoding failed")
        atomic_write_bytes(dst, buf.tobytes())

    def fingerprint(self) -> str:
        return f"render:{self.name}:sweeps={self.at_sweeps}:q={self.jpeg_quality}"

    @property
    def images_at_once(self) -> int:
        """Images the writer may store at once: the renderer's ``images_at_once`` (1 when it has none)."""
        return images_at_once_of(self.render)

    def storing(self) -> contextlib.AbstractContextManager:
        """The renderer's context around the writer's whole image loop, if it has one."""
        return storing_of(self.render)
