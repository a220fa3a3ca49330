"""Warp mode reads no colour from the ego vehicle's own body, on what ``nuav2 synth`` and ``nuav2
convert`` write: the source images' ego-mask pixels painted magenta must not change the output.

Found by review: the mask was tested at the nearest source pixel only, while the colour was read
bilinearly (and JPEG and area reduction smear the body's paint a pixel or two outward); Telea
inpainting then spread that edge colour over the unseen strip behind the ego: 11 % of CAM_BACK's
pixels moved by over 20 levels, its bottom rows turning magenta.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
from e2e_helpers import convert

pytest_plugins = ["test_writer_support", "e2e_support"]

MAGENTA_BGR = (255, 0, 255)


def test_painting_the_ego_body_does_not_change_the_warped_images(synth_log: Path, warp_db: Path,
                                                                 tmp_path: Path):
    from converters.av2 import read_log

    painted = tmp_path / "av2" / "train" / synth_log.name
    shutil.copytree(synth_log, painted)
    scene = read_log(painted)
    bodies = 0
    for cam in scene.rig.cameras:
        body = cam.ego_mask()
        if not body.any():
            continue
        for frame in scene.camera_frames.get(cam.channel, []):
            img = cv2.imread(str(frame.path))
            img[body] = MAGENTA_BGR
            cv2.imwrite(str(frame.path), img, [cv2.IMWRITE_JPEG_QUALITY, 98])
            bodies += 1
    assert bodies > 0, "the synthetic rig has no ego mask to test"
    out = tmp_path / "out"
    convert(painted.parent, out, "--mode", "warp", "--rig", "nuscenes", "--scale", "0.25")
    changed = {}
    for ch in ("CAM_BACK", "CAM_BACK_LEFT", "CAM_BACK_RIGHT", "CAM_FRONT"):
        files = sorted((warp_db / "samples" / ch).glob("*.jpg"))
        assert files, ch
        moved = []
        for f in files:
            ours = cv2.imread(str(out / "samples" / ch / f.name)).astype(np.int16)
            theirs = cv2.imread(str(f)).astype(np.int16)
            moved.append((np.abs(ours - theirs).max(axis=-1) > 20).mean())
        changed[ch] = float(np.mean(moved))
    assert max(changed.values()) < 0.002, changed
