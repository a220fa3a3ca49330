"""Rotation-homography baseline: exact under pure rotation, exact at infinity, the mosaic's choice."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from warp_scenes import camera, city_T_cam, render_plane_world

from nuav2.rig import load_rig
from nuav2.warp.rotation_baseline import (
    RotationSource,
    closest_source_camera,
    optical_axis_angle,
    rotate_into_target,
    rotation_homography,
)


def _median_err(out, exact, covered):
    return float(np.median(np.abs(out - exact).max(axis=2)[covered]))


def test_pure_rotation_equals_the_exact_render_of_the_target_view():
    """Same centre, other orientation and intrinsics: the homography is exact for every depth."""
    src = camera(160, 120, f=110.0)
    K = np.array([[45.0, 0, 30.0], [0, 46.0, 21.0], [0, 0, 1]])
    tgt = dataclasses.replace(camera(64, 40, f=45.0), K=K)
    T_src = city_T_cam(0.0, 0.0, 1.5, yaw=0.0, pitch_down=0.25)
    T_tgt = city_T_cam(0.0, 0.0, 1.5, yaw=0.3, pitch_down=0.15)
    img, _ = render_plane_world(src, T_src)
    exact, _ = render_plane_world(tgt, T_tgt)
    out, covered = rotate_into_target([RotationSource(img, src, T_src)], tgt, T_tgt)
    assert 0.5 < covered.mean() < 1.0  # the turned view leaves part of the target uncovered
    assert _median_err(out, exact, covered) < 0.01
    assert np.all(out[~covered] == 0)


def test_translated_camera_is_exact_for_the_sky_only():
    """Points at infinity do not move with the camera; the ground below does (parallax)."""
    src, tgt = camera(96, 72, f=60.0), camera(64, 48, f=40.0)
    T_src = city_T_cam(0.0, 0.0, 1.5, yaw=0.1)
    T_tgt = city_T_cam(3.0, -2.0, 2.5, yaw=-0.2)
    sky_src, _ = render_plane_world(src, T_src, ground_z=None)
    sky_tgt, _ = render_plane_world(tgt, T_tgt, ground_z=None)
    out, covered = rotate_into_target([RotationSource(sky_src, src, T_src)], tgt, T_tgt)
    assert covered.mean() > 0.6 and _median_err(out, sky_tgt, covered) < 0.01
    T_low = city_T_cam(0.0, 0.0, 1.5, yaw=0.1, pitch_down=0.4)
    ground_src, _ = render_plane_world(src, T_low)
    T_low_tgt = city_T_cam(3.0, -2.0, 2.5, yaw=-0.2, pitch_down=0.4)
    ground_tgt, depth = render_plane_world(tgt, T_low_tgt)
    out, covered = rotate_into_target([RotationSource(ground_src, src, T_low)], tgt, T_low_tgt)
    assert _median_err(out, ground_tgt, covered & np.isfinite(depth)) > 0.05


def test_homography_round_trip_and_identity():
    a, b = camera(80, 60, f=70.0), camera(50, 40, f=30.0)
    T_a, T_b = city_T_cam(1.0, 2.0, 1.5, yaw=0.4, pitch_down=0.1), city_T_cam(-4.0, 0.0, 2.0, yaw=-0.3)
    H_ab, H_ba = rotation_homography(a, T_a, b, T_b), rotation_homography(b, T_b, a, T_a)
    np.testing.assert_allclose(H_ab @ H_ba, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(rotation_homography(a, T_a, a, T_a), np.eye(3), atol=1e-12)
    img = np.random.default_rng(0).integers(0, 256, (60, 80, 3), dtype=np.uint8)
    out, covered = rotate_into_target([RotationSource(img, a, T_a)], a, T_a)
    assert covered.all() and out.dtype == np.uint8 and np.array_equal(out, img)
    with pytest.raises(ValueError, match="calibration says 80x60"):
        RotationSource(img[:10], a, T_a)
    with pytest.raises(ValueError, match="no source image"):
        rotate_into_target([], a, T_a)


def test_mosaic_takes_the_source_closest_to_each_ray_and_skips_the_ego_body():
    tgt = camera(64, 48, f=20.0)  # wide: sees both sources' views
    T_tgt = city_T_cam(0.0, 0.0, 1.5)
    left, right = camera(64, 48, f=40.0, channel="L"), camera(64, 48, f=40.0, channel="R")
    T_left, T_right = city_T_cam(0.0, 0.0, 1.5, yaw=0.5), city_T_cam(0.0, 0.0, 1.5, yaw=-0.5)
    red = np.zeros((48, 64, 3), np.uint8)
    red[..., 0] = 255
    blue = np.zeros((48, 64, 3), np.uint8)
    blue[..., 2] = 255
    sources = [RotationSource(red, left, T_left), RotationSource(blue, right, T_right)]
    out, covered = rotate_into_target(sources, tgt, T_tgt)
    # +yaw turns left (towards +y): the left half of the target image (small u) is closer to the
    # left source's axis, the right half to the right one's; both see the middle columns.
    assert covered[18:30, 28:36].all() and covered.mean() > 0.5
    assert np.all(out[:, :31][covered[:, :31]] == [255, 0, 0])
    assert np.all(out[:, 33:][covered[:, 33:]] == [0, 0, 255])
    lower_half = np.array([[0, 24], [63, 24], [63, 47], [0, 47]], float)
    masked = dataclasses.replace(right, ego_mask_polygons=(lower_half,))
    _, cov_masked = rotate_into_target([RotationSource(blue, masked, T_right)], tgt, T_tgt)
    _, cov_full = rotate_into_target([RotationSource(blue, right, T_right)], tgt, T_tgt)
    assert cov_masked.sum() < 0.7 * cov_full.sum() and not np.any(cov_masked & ~cov_full)


def test_closest_source_camera_between_nuscenes_and_av2():
    nus = load_rig("nuscenes")
    av2 = load_rig("av2")
    pick = {c.channel: closest_source_camera(c, av2).channel for c in nus.cameras}
    assert pick["CAM_FRONT"] == "ring_front_center"
    assert pick["CAM_FRONT_LEFT"] == "ring_front_left"
    assert pick["CAM_FRONT_RIGHT"] == "ring_front_right"
    assert pick["CAM_BACK"] in ("ring_rear_left", "ring_rear_right")
    assert optical_axis_angle(np.eye(4), np.eye(4)) == 0.0
