"""Camera images read at the size they are used at: JPEGs decoded smaller where that is exact.

Training and the warp-mode exposure solve use source images far below their 2048x1550 size; the JPEG
decoder can skip most of the work by decoding at 1/2, 1/4 or 1/8 scale."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

_REDUCED_JPEG = {2: cv2.IMREAD_REDUCED_COLOR_2, 4: cv2.IMREAD_REDUCED_COLOR_4, 8: cv2.IMREAD_REDUCED_COLOR_8}


def jpeg_reduction(path: Path, source_size: tuple[int, int] | None, width: int, height: int) -> int:
    """The largest factor (1, 2, 4 or 8) a JPEG can be decoded smaller by, exactly: it divides both sides
    of ``source_size`` (so the pixel grid keeps its scale, and the intrinsics stay exact) and leaves at
    least ``width`` x ``height``. A 2048x1550 AV2 image trained at 256 px decodes at half size, twice
    as fast; other formats and unknown sizes decode in full."""
    if source_size is None or Path(path).suffix.lower() not in (".jpg", ".jpeg"):
        return 1
    w0, h0 = source_size
    return max([1] + [f for f in _REDUCED_JPEG if w0 % f == 0 and h0 % f == 0
                      and w0 // f >= width and h0 // f >= height])


def jpeg_cut_short(path: Path) -> bool:
    """Whether a JPEG file lacks its end-of-image marker (FF D9) at its end, i.e. was cut short; cv2
    decodes such a file without an error (the missing rows grey), so warp and render modes check this
    first. Reads only the file's last bytes; other formats are never "cut short" here."""
    if Path(path).suffix.lower() not in (".jpg", ".jpeg"):
        return False
    try:
        with open(path, "rb") as f:
            f.seek(0, 2)
            size = f.tell()
            f.seek(max(0, size - 64))
            tail = f.read()
    except OSError:
        return False  # the decoder reports an unreadable file itself
    return not tail.rstrip(b"\x00").endswith(b"\xff\xd9")


def load_image_u8(path: Path, width: int, height: int,
                  source_size: tuple[int, int] | None = None) -> np.ndarray:
    """Read an image file as uint8 RGB, area-resized to width x height (decoded at a reduced size first
    where :func:`jpeg_reduction` allows, given the file's ``source_size``)."""
    f = jpeg_reduction(path, source_size, width, height)
    bgr = cv2.imread(str(path), _REDUCED_JPEG[f] if f > 1 else cv2.IMREAD_COLOR)
    if bgr is None:
        raise ValueError(f"{path}: camera image missing or unreadable")
    if jpeg_cut_short(path):
        raise ValueError(f"{path}: camera image cut short (no JPEG end-of-image marker)")
    if bgr.shape[:2] != (height, width):
        bgr = cv2.resize(bgr, (width, height), interpolation=cv2.INTER_AREA)
    return np.ascontiguousarray(bgr[:, :, ::-1])
