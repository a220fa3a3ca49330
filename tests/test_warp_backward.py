"""Backward warp on hand-made scenes: exact renders of a textured plane, occlusion, moving boxes, blending."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from warp_scenes import camera, city_T_cam, render_plane_world

from nuav2.geometry import T_inverse, make_T
from nuav2.warp.backward_warp import BlendConfig, SourceView, fill_uncovered, warp_from_sources
from nuav2.warp.depth_proxy import GroundSurface, ProxyGeometry, render_depth_proxy

GROUND = GroundSurface.horizontal(0.0)


def geometry(boxes=()) -> ProxyGeometry:
    if not boxes:
        return ProxyGeometry(GROUND, np.zeros((0, 3)), np.zeros(0), np.zeros((0, 4, 4)), np.zeros((0, 3)))
    return ProxyGeometry(GROUND, np.zeros((0, 3)), np.zeros(0), np.stack([b[0] for b in boxes]),
                         np.array([b[1] for b in boxes], dtype=float))


def source(cam, T, boxes=(), ts=0, image=None) -> SourceView:
    img, _ = render_plane_world(cam, T, list(boxes))
    proxy = render_depth_proxy(cam, T, geometry(boxes))
    return SourceView(img if image is None else image, cam, T, ts, cam, proxy.inverse_depth())


def test_identity_warp_returns_the_source_image():
    cam = camera(64, 48)
    T = city_T_cam(10.0, -5.0, 1.5, yaw=0.7, pitch_down=0.1)
    src = source(cam, T)
    target = render_depth_proxy(cam, T, geometry())
    out = warp_from_sources(target, [src], 0)
    assert np.all(out.coverage)
    np.testing.assert_allclose(out.rgb, src.image, atol=2e-3)
    src8 = SourceView(np.rint(src.image * 255).astype(np.uint8), cam, T, 0, cam, src.inv_depth)
    np.testing.assert_allclose(warp_from_sources(target, [src8], 0).rgb, src.image, atol=1 / 255 + 2e-3)


def test_ego_body_pixels_of_a_source_are_never_used():
    cam = camera(64, 48)
    T = city_T_cam(0.0, 0.0, 1.5, pitch_down=0.1)
    src = source(cam, T)
    valid = np.ones((48, 64), bool)
    valid[30:] = False  # the bottom rows show the ego's own hood
    masked = SourceView(src.image, cam, T, 0, cam, src.inv_depth, valid)
    out = warp_from_sources(render_depth_proxy(cam, T, geometry()), [masked], 0)
    assert np.all(out.coverage[:29]) and not np.any(out.coverage[31:])


def test_warp_matches_the_exact_render_of_another_pose():
    src_cam = camera(160, 120, f=100.0)
    tgt_cam = camera(64, 48, f=40.0)
    T_src = city_T_cam(3000.0, 1000.0, 1.4, yaw=0.0, pitch_down=0.12)
    T_tgt = city_T_cam(3000.8, 1000.3, 1.8, yaw=0.12, pitch_down=0.2)
    target = render_depth_proxy(tgt_cam, T_tgt, geometry())
    out = warp_from_sources(target, [source(src_cam, T_src)], 0)
    exact, _ = render_plane_world(tgt_cam, T_tgt)
    cov = out.coverage
    assert cov.mean() > 0.6
    # Where the source resolves the texture (ground within 8 m: under 0.5 m per source pixel, the
    # texture's period is ~9 m) and in the sky (a pure rotation); elsewhere bilinear resampling of
    # the aliased far texture dominates.
    resolved = cov & ((target.depth < 8.0) | np.isinf(target.depth))
    assert resolved.sum() > 0.4 * cov.sum()
    err = np.abs(out.rgb - exact)[resolved]
    assert err.mean() < 0.003 and err.max() < 0.02
    assert np.all(np.isfinite(out.rgb))


def test_occluded_ground_is_not_coloured_by_the_occluder():
    cam = camera(96, 72, f=60.0)
    red = (1.0, 0.0, 0.0)
    box = (make_T(np.eye(3), [6.0, 0.0, 0.8]), (1.0, 1.0, 1.6), red)
    T_src = city_T_cam(0.0, 0.0, 1.5, pitch_down=0.1)
    T_tgt = city_T_cam(0.0, 2.5, 1.5, yaw=-0.25, pitch_down=0.1)  # sideways: sees behind the box
    src = source(cam, T_src, [box])
    target = render_depth_proxy(cam, T_tgt, geometry([box]))
    exact, _ = render_plane_world(cam, T_tgt, [box])
    out = warp_from_sources(target, [src], 0)
    ground_px = np.any(exact != np.array(red, np.float32), axis=2)
    reddish = (out.rgb[..., 0] > 0.8) & (out.rgb[..., 1] < 0.2) & (out.rgb[..., 2] < 0.2)
    assert not np.any(reddish & ground_px & out.coverage)
    # The hidden ground is there and uncovered; without the visibility test it would be painted red.
    hidden = ground_px & ~out.coverage & (target.box_index < 0) & np.isfinite(target.depth)
    assert hidden.sum() > 20
    blind = SourceView(src.image, cam, T_src, 0, cam, np.zeros_like(src.inv_depth))
    out_blind = warp_from_sources(target, [blind], 0)
    red_blind = (out_blind.rgb[..., 0] > 0.8) & (out_blind.rgb[..., 1] < 0.2)
    assert np.sum(red_blind & hidden) > 10


def test_moving_box_points_travel_with_the_box():
    cam = camera(96, 72, f=60.0)
    blue = (0.0, 0.0, 1.0)
    size = (4.0, 2.0, 1.5)
    box_T_at_target = make_T(np.eye(3), [10.0, 0.0, 0.75])
    box_T_at_source = make_T(np.eye(3), [11.5, 0.0, 0.75])  # moved 1.5 m forward by the source time
    T = city_T_cam(0.0, 2.0, 1.5, yaw=-0.1, pitch_down=0.05)
    src = source(cam, T, [(box_T_at_source, size, blue)], ts=100_000_000)
    target = render_depth_proxy(cam, T, geometry([(box_T_at_target, size, blue)]))
    on_box = cv2.erode((target.box_index == 0).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    assert on_box.sum() > 100  # interior: the silhouette's pixels blend with the ground bilinearly
    motion = (box_T_at_source @ T_inverse(box_T_at_target))[None]
    out = warp_from_sources(target, [src], 0, motions=[motion])
    blue_px = (out.rgb[..., 2] > 0.9) & (out.rgb[..., 0] < 0.1)
    assert np.all(out.coverage[on_box]) and blue_px[on_box].mean() > 0.97
    out_static = warp_from_sources(target, [src], 0, motions=[np.eye(4)[None]])
    blue_static = (out_static.rgb[..., 2] > 0.9) & (out_static.rgb[..., 0] < 0.1)
    assert blue_static[on_box].mean() < 0.9  # pretending the box stood still takes ground colours
    # A box absent at the source time (NaN motion) gives no colour to its pixels.
    out_gone = warp_from_sources(target, [src], 0, motions=[np.full((1, 4, 4), np.nan)])
    assert not np.any(out_gone.coverage[target.box_index == 0])


def test_sources_behind_the_target_give_no_coverage_and_no_nan():
    cam = camera(48, 36)
    T_tgt = city_T_cam(0.0, 0.0, 1.5, pitch_down=0.1)
    T_src = city_T_cam(0.0, 0.0, 1.5, yaw=np.pi, pitch_down=0.1)  # looking backwards
    target = render_depth_proxy(cam, T_tgt, geometry())
    with np.errstate(invalid="raise", divide="raise"):
        out = warp_from_sources(target, [source(cam, T_src)], 0)
    assert not np.any(out.coverage) and np.all(out.rgb == 0)
    out2 = warp_from_sources(target, [], 0)
    assert not np.any(out2.coverage)


def test_empty_depth_warps_directions_only_and_stays_finite():
    cam = camera(48, 36)
    T_tgt = city_T_cam(0.0, 0.0, 1.5, yaw=0.2)
    target = render_depth_proxy(cam, T_tgt, ProxyGeometry.empty())  # every pixel at infinity
    src_T = city_T_cam(5.0, 3.0, 1.5)  # translation does not matter for directions
    img, _ = render_plane_world(cam, src_T, ground_z=None)  # a sky-only world
    empty_src = render_depth_proxy(cam, src_T, ProxyGeometry.empty())
    with np.errstate(invalid="raise", divide="raise"):
        out = warp_from_sources(target, [SourceView(img, cam, src_T, 0, cam, empty_src.inverse_depth())], 0)
    exact, _ = render_plane_world(cam, T_tgt, ground_z=None)
    assert out.coverage.mean() > 0.5 and np.all(np.isfinite(out.rgb))
    assert np.abs(out.rgb - exact)[out.coverage].max() < 0.01


def test_overlapping_sources_blend_and_single_sources_pass_through():
    cam = camera(64, 48)
    T_tgt = city_T_cam(0.0, 0.0, 1.5, pitch_down=0.1)
    a = np.full((48, 64, 3), 0.2, np.float32)
    b = np.full((48, 64, 3), 0.8, np.float32)
    src_a = source(cam, city_T_cam(0.0, 0.0, 1.5, yaw=0.3, pitch_down=0.1), image=a)
    src_b = source(cam, city_T_cam(0.0, 0.0, 1.5, yaw=-0.3, pitch_down=0.1), image=b)
    target = render_depth_proxy(cam, T_tgt, geometry())
    out = warp_from_sources(target, [src_a, src_b], 0)
    both = out.n_sources == 2
    only_a = (out.n_sources == 1) & (np.arange(64)[None, :] < 32)
    assert both.sum() > 50 and only_a.sum() > 50
    assert np.all((out.rgb[both] >= 0.2 - 1e-6) & (out.rgb[both] <= 0.8 + 1e-6))
    np.testing.assert_allclose(out.rgb[only_a], 0.2, atol=1e-6)
    # Feathering: in the overlap the colour moves monotonically from a's side to b's side.
    row = out.rgb[30, :, 0][both[30]]
    assert row[0] < row[-1] and np.all(np.diff(row) >= -1e-6)
    # A later source time is down-weighted.
    src_b_late = SourceView(b, cam, src_b.city_T_cam, 200_000_000, cam, src_b.inv_depth)
    out_late = warp_from_sources(target, [src_a, src_b_late], 0, config=BlendConfig())
    assert out_late.rgb[both][:, 0].mean() < out.rgb[both][:, 0].mean()


def test_fill_uncovered_modes():
    rgb = np.zeros((20, 20, 3), np.float32)
    rgb[:, :10] = 0.6
    covered = np.zeros((20, 20), bool)
    covered[:, :10] = True
    c = fill_uncovered(rgb, covered, (0.1, 0.2, 0.3), mode="color")
    np.testing.assert_allclose(c[:, 15], [[0.1, 0.2, 0.3]] * 20)
    np.testing.assert_allclose(c[:, :10], 0.6)
    p = fill_uncovered(rgb, covered, mode="inpaint")
    assert np.all(np.isfinite(p)) and np.allclose(p[:, 10:12], 0.6, atol=0.01)
    none = fill_uncovered(rgb, np.zeros((20, 20), bool), (0.5, 0.5, 0.5), mode="inpaint")
    np.testing.assert_allclose(none, 0.5)
    with pytest.raises(ValueError, match="fill mode"):
        fill_uncovered(rgb, covered, mode="blur")


def test_source_view_checks_shapes():
    cam = camera(16, 12)
    with pytest.raises(ValueError, match="float32 or uint8"):
        SourceView(np.zeros((12, 16, 3)), cam, np.eye(4), 0, cam, np.zeros((12, 16), np.float32))
    with pytest.raises(ValueError, match="inverse depth shape"):
        SourceView(np.zeros((12, 16, 3), np.float32), cam, np.eye(4), 0, cam, np.zeros((6, 8), np.float32))
