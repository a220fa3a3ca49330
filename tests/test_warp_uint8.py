"""The writer's uint8 path of the warp gives the same bytes as rounding the float render, and the one-pass
hole closing the same depth as its numpy form."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from test_warp_backward import geometry, source
from warp_scenes import camera, city_T_cam

from nuav2.warp._kernels import blend_to_uint8_kernel
from nuav2.warp.backward_warp import fill_uncovered, to_uint8, warp_from_sources, warp_to_uint8
from nuav2.warp.depth_proxy import close_holes, render_depth_proxy


def float_path(target, sources, mode, background=(0.3, 0.6, 0.9)):
    """What the writer stored before: the float blend, filled, rounded to uint8."""
    res = warp_from_sources(target, sources, 0)
    return to_uint8(fill_uncovered(res.rgb, res.coverage, background, mode)), res.coverage


@pytest.mark.parametrize("mode", ["inpaint", "color"])
@pytest.mark.parametrize("yaws", [(0.0,), (0.35,), (0.35, -0.3), (np.pi,)])
def test_uint8_path_is_the_rounded_float_path(mode, yaws):
    cam = camera(64, 48)
    T_tgt = city_T_cam(0.0, 0.0, 1.5, pitch_down=0.05)  # the sky above the horizon is never covered
    rng = np.random.default_rng(len(yaws))
    sources = []
    for k, yaw in enumerate(yaws):
        img = rng.random((48, 64, 3), dtype=np.float32)
        if k % 2:
            img = np.rint(img * 255).astype(np.uint8)
        sources.append(source(cam, city_T_cam(0.0, 0.2 * k, 1.5, yaw=yaw, pitch_down=0.1), image=img))
    target = render_depth_proxy(cam, T_tgt, geometry())
    want, cov = float_path(target, sources, mode)
    got, got_cov = warp_to_uint8(target, sources, 0, background=(0.3, 0.6, 0.9), mode=mode)
    assert np.array_equal(got_cov, cov) and np.array_equal(got, want)


def test_uint8_path_refuses_an_unknown_fill_mode():
    target = render_depth_proxy(camera(16, 12), city_T_cam(0.0, 0.0, 1.5), geometry())
    with pytest.raises(ValueError, match="fill mode"):
        warp_to_uint8(target, [], 0, mode="blur")


def test_blend_kernel_matches_numpy_at_every_rounding_edge():
    rng = np.random.default_rng(0)
    n = 20000
    wsum = rng.random(n) * 3
    wsum[::7] = 0.0
    wsum[::11] = 1e-320  # > 0 in float64, 0 in float32: rounded colour but not covered
    acc = wsum[:, None] * rng.random((n, 3))
    acc[::5] = wsum[::5, None] * (rng.integers(0, 256, (len(acc[::5]), 3)) + 0.5) / 255  # halves
    acc[::13] = wsum[::13, None] * 1.0000001  # just above 1: clipped
    rgb = np.where(wsum[:, None] > 0, acc / np.maximum(wsum, 1e-300)[:, None], 0.0).astype(np.float32)
    img8 = np.empty((100, 200, 3), np.uint8)
    hole = np.empty((100, 200), np.uint8)
    n_holes = blend_to_uint8_kernel(acc, wsum, img8, hole)
    assert np.array_equal(img8.reshape(n, 3), to_uint8(rgb))
    covered = wsum.astype(np.float32) > 0
    assert np.array_equal(hole.reshape(n) == 0, covered) and n_holes == n - covered.sum()


def test_every_uint8_survives_the_float_round_trip():
    v = np.arange(256, dtype=np.uint8)
    assert np.array_equal(to_uint8(v.astype(np.float32) / 255.0), v)


def test_inpaint_in_place_matches_a_separate_output():
    rng = np.random.default_rng(1)
    for _ in range(20):
        img = rng.integers(0, 256, (37, 53, 3), dtype=np.uint8)
        mask = (rng.random((37, 53)) < rng.uniform(0.05, 0.6)).astype(np.uint8)
        want = cv2.inpaint(img, mask, 3, cv2.INPAINT_TELEA)
        cv2.inpaint(img, mask, 3, cv2.INPAINT_TELEA, dst=img)
        assert np.array_equal(img, want)


def close_holes_numpy(depth, fill_px):
    """The numpy form close_holes replaced (temporaries per step)."""
    empty = ~np.isfinite(depth)
    if not np.any(empty) or np.all(empty):
        return depth
    inv = np.where(empty, 0.0, 1.0 / np.where(empty, 1.0, depth)).astype(np.float32)
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (fill_px, fill_px))
    closed = cv2.morphologyEx(inv, cv2.MORPH_CLOSE, kernel, borderType=cv2.BORDER_REPLICATE)
    fill = empty & (closed > 0)
    out = depth.copy()
    out[fill] = 1.0 / closed[fill].astype(np.float64)
    return out


@pytest.mark.parametrize("empty_share", [0.0, 0.3, 0.8, 1.0])
def test_close_holes_matches_its_numpy_form(empty_share):
    rng = np.random.default_rng(2)
    depth = rng.uniform(0.5, 80.0, (48, 64))
    depth[rng.random(depth.shape) < empty_share] = np.inf
    for fill_px in (1, 3, 5):
        assert np.array_equal(close_holes(depth, fill_px), close_holes_numpy(depth, fill_px))
