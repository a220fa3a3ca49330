"""Naive baseline: closest source camera by optical axis, resized to the target intrinsics."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from warp_scenes import camera, city_T_cam, render_plane_world

from nuav2.rig import load_rig
from nuav2.warp.naive import closest_source_camera, optical_axis_angle, resize_to_intrinsics


def test_resize_equals_the_exact_render_at_the_other_intrinsics():
    src = camera(160, 120, f=110.0)
    K = np.array([[45.0, 0, 30.0], [0, 46.0, 21.0], [0, 0, 1]])
    tgt = dataclasses.replace(camera(64, 40, f=45.0), K=K)
    T = city_T_cam(0.0, 0.0, 1.5, pitch_down=0.25)  # same pose: the resize is exact up to resampling
    img, _ = render_plane_world(src, T)
    exact, _ = render_plane_world(tgt, T)
    out, covered = resize_to_intrinsics(img, src, tgt)
    assert covered.mean() > 0.9
    err = np.abs(out - exact).max(axis=2)[covered]
    assert np.median(err) < 0.01
    assert np.all(out[~covered] == 0)


def test_resize_with_identical_cameras_is_identity_and_checks_size():
    cam = camera(32, 24)
    img = np.random.default_rng(0).random((24, 32, 3)).astype(np.float32)
    out, covered = resize_to_intrinsics(img, cam, cam)
    assert np.all(covered)
    np.testing.assert_allclose(out, img, atol=1e-6)
    with pytest.raises(ValueError, match="calibration says 32x24"):
        resize_to_intrinsics(img[:10], cam, cam)


def test_closest_source_camera_between_nuscenes_and_av2():
    nus = load_rig("nuscenes")
    av2 = load_rig("av2")
    pick = {c.channel: closest_source_camera(c, av2).channel for c in nus.cameras}
    assert pick["CAM_FRONT"] == "ring_front_center"
    assert pick["CAM_FRONT_LEFT"] == "ring_front_left"
    assert pick["CAM_FRONT_RIGHT"] == "ring_front_right"
    assert pick["CAM_BACK"] in ("ring_rear_left", "ring_rear_right")
    assert optical_axis_angle(np.eye(4), np.eye(4)) == 0.0
