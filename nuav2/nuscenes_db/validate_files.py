"""File checks: every sample_data file and map PNG exists, lidar files hold whole 5-float rows, image
headers match the table's width and height and, on request, every image decodes to the end."""

from __future__ import annotations

import os
from pathlib import Path

from nuav2.nuscenes_db.images import decode_problem
from nuav2.nuscenes_db.validate_tables import _S, LIDAR_ROW_BYTES, MODALITIES, TableStore
from nuav2.progress import progress_bar


class FileChecks(TableStore):
    """The files the tables point to."""

    def _check_files(self, check_images: bool, decode_images: bool = False) -> None:
        tokens = self.tokens("map")
        for i, rel in enumerate(self.col("map", "filename", _S)):
            msg = None if rel is None else _relpath_problem(rel) or _png_problem(self.dataroot / rel)
            if msg:
                self.add("map", tokens[i], "filename", msg, "file")
        table = "sample_data"
        tokens = self.tokens(table)
        names = self.col(table, "filename", _S)
        (widths, w_ok), (heights, h_ok) = self.ints(table, "width"), self.ints(table, "height")
        modality = self._sample_data_columns()["modality"]
        cam, lidar = MODALITIES.index("camera"), MODALITIES.index("lidar")
        listing: dict[str, dict[str, os.DirEntry]] = {}
        for i in progress_bar(range(len(names)), desc="sample_data files", unit="file",
                              disable=not self.progress, mininterval=1.0):
            rel = names[i]
            if rel is None:
                continue
            bad = _relpath_problem(rel)
            if bad:
                self.add(table, tokens[i], "filename", bad, "file")
                continue
            folder, base = os.path.split(rel)
            if folder not in listing:
                listing[folder] = _scan(self.dataroot / folder)
            entry = listing[folder].get(base)
            if entry is None:
                self.add(table, tokens[i], "filename", f"file not found: {self.dataroot / rel}",
                         "missing_file")
            elif modality[i] == lidar:
                self._check_lidar_file(tokens[i], rel, entry)
            elif modality[i] == cam and w_ok[i] and h_ok[i]:
                if widths[i] <= 0 or heights[i] <= 0:
                    self.add(table, tokens[i], "width", f"camera image size {widths[i]}x{heights[i]} is not "
                             "positive", "image_size")
                if check_images:
                    self._check_image(tokens[i], rel, (int(widths[i]), int(heights[i])), decode_images)

    def _check_lidar_file(self, token: str, rel: str, entry: os.DirEntry) -> None:
        if not rel.endswith(".bin"):
            self.add("sample_data", token, "filename", f"{rel}: a lidar file must end in .bin "
                     "(LidarPointCloud asserts it)", "lidar_file")
        size = entry.stat().st_size
        if size % LIDAR_ROW_BYTES:  # 0 bytes is a sweep without points: LidarPointCloud reads (4, 0)
            self.add("sample_data", token, "filename", f"{rel}: {size} bytes is not a multiple of "
                     f"{LIDAR_ROW_BYTES} (5 float32 per point)", "lidar_file")

    def _check_image(self, token: str, rel: str, wh: tuple[int, int], decode: bool) -> None:
        size = image_size(self.dataroot / rel)
        if isinstance(size, str):
            self.add("sample_data", token, "filename", f"{rel}: {size}", "image_file")
            return
        problem = decode_problem(self.dataroot / rel) if decode else None
        if problem:
            self.add("sample_data", token, "filename", f"{rel}: {problem}", "image_decode")
        if size != wh:
            self.add("sample_data", token, "width", f"width x height {wh[0]}x{wh[1]} but the image header of "
                     f"{rel} says {size[0]}x{size[1]}", "image_size")


def _relpath_problem(rel: str) -> str | None:
    if not rel or os.path.isabs(rel) or ".." in Path(rel).parts:
        return f"filename {rel!r} must be a non-empty path relative to dataroot"
    return None


def _scan(folder: Path) -> dict[str, os.DirEntry]:
    """One listing per folder instead of one stat per file (1M files stat slowly on network disks)."""
    try:
        with os.scandir(folder) as it:
            return {e.name: e for e in it}
    except OSError:
        return {}


def _png_problem(path: Path) -> str | None:
    try:
        with open(path, "rb") as f:
            head = f.read(24)
    except OSError as e:
        return f"map mask not readable: {path} ({e.strerror or e})"
    if head[:8] != b"\x89PNG\r\n\x1a\n" or head[12:16] != b"IHDR":
        return f"map mask {path} is not a PNG"
    if int.from_bytes(head[16:20], "big") == 0 or int.from_bytes(head[20:24], "big") == 0:
        return f"map mask {path} has zero width or height"
    return None


_SOF_MARKERS = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}  # not DHT, JPG, DAC
_STANDALONE_MARKERS = frozenset([0x01, *range(0xD0, 0xD8)])  # TEM, RSTn: no length field


def image_size(path: str | Path) -> tuple[int, int] | str:
    """(width, height) from a JPEG's SOF (or a PNG's IHDR) header without decoding; else what is wrong."""
    try:
        with open(path, "rb") as f:
            head = f.read(2)
            if head == b"\x89P":
                rest = f.read(22)
                if rest[:6] != b"NG\r\n\x1a\n" or rest[10:14] != b"IHDR":
                    return "not a PNG (bad signature)"
                return int.from_bytes(rest[14:18], "big"), int.from_bytes(rest[18:22], "big")
            if head != b"\xff\xd8":
                return "not a JPEG (no SOI marker)"
            while True:
                byte = f.read(1)
                if byte != b"\xff":
                    return "truncated JPEG: no SOF header" if not byte else "corrupt JPEG: expected a marker"
                marker = f.read(1)
                while marker == b"\xff":  # fill bytes
                    marker = f.read(1)
                if not marker:
                    return "truncated JPEG: no SOF header"
                if marker[0] in _STANDALONE_MARKERS:
                    continue
                if marker[0] in (0xD9, 0xDA):
                    return "corrupt JPEG: image data before any SOF header"
                seg = f.read(2)
                if len(seg) < 2 or int.from_bytes(seg, "big") < 2:
                    return "truncated or corrupt JPEG segment header"
                if marker[0] in _SOF_MARKERS:
                    sof = f.read(5)  # precision, height, width
                    if len(sof) < 5:
                        return "truncated JPEG SOF header"
                    return int.from_bytes(sof[3:5], "big"), int.from_bytes(sof[1:3], "big")
                f.seek(int.from_bytes(seg, "big") - 2, os.SEEK_CUR)
    except OSError as e:
        return f"not readable ({e.strerror or e})"
