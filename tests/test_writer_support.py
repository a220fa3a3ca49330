"""Shared inputs for the writer/convert tests (no tests here): AV2 logs built from the real fixture.

The real fixture log ships no images and one sweep. ``imaged_log`` links its real files into
a temp log and adds calibration plus blank JPEGs (right size) at real pose timestamps near the
sweep, one per camera at its AV2 phase and one 50 ms later, so native mode has key and
non-key images whose ego poses are exact rows of the AV2 pose table.
"""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest

FIXTURE_SWEEP_NS = 315973157959879000
# Camera -> phase (ms) to the sweep, as AV2's cameras fire (av2_format.md section 7).
CAMERA_PHASES_MS = {"ring_front_center": -10.0, "ring_front_left": -22.5, "ring_front_right": 2.5,
                    "ring_side_left": 12.5, "ring_side_right": 17.5, "ring_rear_left": -2.5,
                    "ring_rear_right": -17.5, "stereo_front_left": -10.0, "stereo_front_right": -10.0}


def link_log(src_log: Path, dst_root: Path, log_id: str, calibration: Path | None = None) -> Path:
    """A new log dir named ``log_id`` whose files are symlinks to ``src_log``'s (no copy of the data)."""
    dst = dst_root / log_id
    for f in sorted(src_log.rglob("*")):
        if f.is_file():
            target = dst / f.relative_to(src_log)
            target.parent.mkdir(parents=True, exist_ok=True)
            os.symlink(f.resolve(), target)
    if calibration is not None:
        (dst / "calibration").mkdir(parents=True, exist_ok=True)
        for f in calibration.iterdir():
            os.symlink(f.resolve(), dst / "calibration" / f.name)
    return dst


def add_blank_images(log_dir: Path, calibration: Path,
                     phases_ms: dict[str, float] = CAMERA_PHASES_MS) -> dict:
    """Write black JPEGs at pose-table timestamps nearest to sweep + phase and + phase + 50 ms.

    Returns {channel: [timestamp_ns, ...]}.
    """
    poses = pd.read_feather(log_dir / "city_SE3_egovehicle.feather")["timestamp_ns"].to_numpy()
    intr = pd.read_feather(calibration / "intrinsics.feather").set_index("sensor_name")
    out: dict[str, list[int]] = {}
    for ch, phase in phases_ms.items():
        w, h = int(intr.loc[ch, "width_px"]), int(intr.loc[ch, "height_px"])
        ok, jpg = cv2.imencode(".jpg", np.zeros((h, w, 3), np.uint8))
        assert ok
        cam_dir = log_dir / "sensors" / "cameras" / ch
        cam_dir.mkdir(parents=True, exist_ok=True)
        out[ch] = []
        for extra_ms in (0.0, 50.0):
            want = FIXTURE_SWEEP_NS + int((phase + extra_ms) * 1e6)
            ts = int(poses[np.argmin(np.abs(poses - want))])
            (cam_dir / f"{ts}.jpg").write_bytes(jpg.tobytes())
            out[ch].append(ts)
    return out


@pytest.fixture(scope="session")
def imaged_log(av2_fixture_log: Path, av2_fixture_calibration: Path, tmp_path_factory) -> tuple[Path, dict]:
    """(log dir, {channel: image timestamps}) of the real fixture log plus calibration and images."""
    root = tmp_path_factory.mktemp("imaged_av2") / "val"
    log_dir = link_log(av2_fixture_log, root, av2_fixture_log.name, av2_fixture_calibration)
    return log_dir, add_blank_images(log_dir, av2_fixture_calibration)


@pytest.fixture(scope="session")
def native_db(imaged_log, tmp_path_factory) -> Path:
    """The imaged fixture log converted in native mode (symlinked images, every sweep a sample)."""
    from nuav2.convert import ConvertOptions, convert_av2

    out = tmp_path_factory.mktemp("native_db")
    report = convert_av2(imaged_log[0].parent, out, ConvertOptions(image_link="symlink", show_progress=False))
    assert report.ok, report.failed
    return out
