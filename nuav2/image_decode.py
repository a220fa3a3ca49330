"""Camera images read at the size they are used at: JPEGs decoded smaller where that is exact.

Training and the warp-mode exposure solve use source images far below their 2048x1550 size; the JPEG
decoder can skip most of the work by decoding at 1/2, 1/4 or 1/8 scale."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from nuav2.nuscenes_db.images import ImageSourceError

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


def jpeg_cut_short(data: bytes) -> bool:
    """Whether JPEG bytes were cut short: no end-of-image marker (FF D9) after the first scan. cv2 decodes
    such a file without an error (the missing rows grey), so warp and render modes check this first.
    The header segments are walked by their lengths (an EXIF thumbnail's own markers are skipped);
    entropy-coded data never holds FF D9. Bytes after the marker are allowed, and anything that is not
    JPEG content is left to the decoder."""
    if data[:2] != b"\xff\xd8":
        return False
    pos = 2
    while True:
        if pos + 4 > len(data):
            return True  # the headers end before the first scan
        if data[pos] != 0xFF:
            return False  # not a marker: the decoder judges it
        marker = data[pos + 1]
        if marker == 0xFF:  # fill byte
            pos += 1
        elif marker == 0xDA:  # start of scan
            return data.find(b"\xff\xd9", pos + 2) < 0
        elif marker == 0xD9:
            return False  # an end before any scan: the decoder judges it
        elif 0xD0 <= marker <= 0xD7 or marker == 0x01:  # markers without a length
            pos += 2
        else:
            pos += 2 + int.from_bytes(data[pos + 2:pos + 4], "big")


def read_bgr(path: Path, flags: int = cv2.IMREAD_COLOR) -> np.ndarray:
    """A camera image decoded by cv2 from its bytes, read once; ImageSourceError (a ValueError) naming
    the file when it is missing, does not decode, or is a JPEG cut short."""
    try:
        data = Path(path).read_bytes()
    except OSError as e:
        raise ImageSourceError(f"{path}: camera image missing or unreadable ({e.strerror})") from None
    if jpeg_cut_short(data):
        raise ImageSourceError(f"{path}: camera image cut short (no JPEG end-of-image marker)")
    bgr = cv2.imdecode(np.frombuffer(data, np.uint8), flags)
    if bgr is None:
        raise ImageSourceError(f"{path}: camera image does not decode")
    return bgr


def load_image_u8(path: Path, width: int, height: int,
                  source_size: tuple[int, int] | None = None) -> np.ndarray:
    """Read an image file as uint8 RGB, area-resized to width x height (decoded at a reduced size first
    where :func:`jpeg_reduction` allows, given the file's ``source_size``)."""
    f = jpeg_reduction(path, source_size, width, height)
    bgr = read_bgr(path, _REDUCED_JPEG[f] if f > 1 else cv2.IMREAD_COLOR)
    if bgr.shape[:2] != (height, width):
        bgr = cv2.resize(bgr, (width, height), interpolation=cv2.INTER_AREA)
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)  # same bytes as a flipped copy, 50-90x faster
