"""Camera images of an AV2 log (``sensors/cameras/<channel>/<ts_ns>.jpg``), time-sorted per channel."""

from __future__ import annotations

import logging
import re
from pathlib import Path

from converters.av2.errors import AV2LogError, require_file
from nuav2.scene import CameraFrame

log = logging.getLogger(__name__)

CAMERAS_DIR = Path("sensors") / "cameras"
IMAGE_NAME_RE = re.compile(r"^(\d+)\.jpg$")


def list_camera_frames(log_dir: Path, channels: list[str],
                       require_cameras: bool) -> dict[str, list[CameraFrame]]:
    """Frames per rig channel. With ``require_cameras`` a missing or empty channel is an error,
    otherwise it is logged and left empty."""
    frames: dict[str, list[CameraFrame]] = {}
    for ch in channels:
        cam_dir = log_dir / CAMERAS_DIR / ch
        found: list[CameraFrame] = []
        stray: list[str] = []
        if cam_dir.is_dir():
            for p in cam_dir.iterdir():
                m = IMAGE_NAME_RE.match(p.name)
                if m:
                    require_file(p)  # a dangling link or a directory fails the log, as a bad JPEG does
                    found.append(CameraFrame(ch, int(m.group(1)), p))
                else:
                    stray.append(p.name)
        if stray:
            log.warning("%s: ignored %d entries not named <timestamp_ns>.jpg, e.g. %s", cam_dir, len(stray),
                        sorted(stray)[:3])
        if not found:
            reason = "camera directory not found" if not cam_dir.is_dir() else "no <timestamp_ns>.jpg images"
            if require_cameras:
                raise AV2LogError(cam_dir, f"{reason} for rig camera '{ch}' (--allow-missing-cameras "
                                           "converts the log without the cameras it lacks)")
            log.info("%s: %s; camera '%s' left empty", cam_dir, reason, ch)
        found.sort(key=lambda f: f.timestamp_ns)
        for a, b in zip(found, found[1:]):
            if a.timestamp_ns == b.timestamp_ns:
                raise AV2LogError(cam_dir, f"files {a.path.name} and {b.path.name} name the same timestamp")
        frames[ch] = found
    root = log_dir / CAMERAS_DIR
    present = [p.name for p in root.iterdir() if p.is_dir()] if root.is_dir() else []
    unused = sorted(n for n in present if n not in frames)
    if unused:
        log.info("%s: camera dir(s) %s are not in the rig and are not read", root, unused)
    return frames
