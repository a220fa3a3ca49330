"""Fixed-point resampling and the ordering variants MapTR matches against."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from nuav2.maptr.fixed_points import (
    PAD_VALUE,
    fixed_point_targets,
    is_closed,
    ordering_variants,
    polyline_length,
    resample_polyline,
)
from nuav2.maptr.vectorize import CLASS_IDS

coords = st.floats(-50, 50, allow_nan=False, allow_infinity=False).map(lambda v: round(v, 6))


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(coords, coords), min_size=1, max_size=12), st.integers(2, 40))
def test_resample_is_even_on_the_line_and_keeps_ends(raw, num):
    pts = np.array(raw, dtype=np.float64)
    out = resample_polyline(pts, num)
    assert out.shape == (num, 2) and np.all(np.isfinite(out))
    np.testing.assert_array_equal(out[0], pts[0])
    np.testing.assert_array_equal(out[-1], pts[-1])
    total = polyline_length(pts)
    if total > 1e-6:
        # consecutive samples are never further apart along the line than total/(num-1) (chords <= arcs)
        gaps = np.linalg.norm(np.diff(out, axis=0), axis=1)
        assert np.all(gaps <= total / (num - 1) + 1e-9)
        # every sample lies on the polyline
        assert max(_distance_to_polyline(p, pts) for p in out) < 1e-7


def _distance_to_polyline(p: np.ndarray, pts: np.ndarray) -> float:
    a, b = pts[:-1], pts[1:]
    ab = b - a
    denom = np.maximum(np.sum(ab * ab, axis=1), 1e-300)
    t = np.clip(np.sum((p - a) * ab, axis=1) / denom, 0.0, 1.0)
    return float(np.min(np.linalg.norm(a + t[:, None] * ab - p, axis=1)))


def test_resample_straight_line_is_exactly_even():
    out = resample_polyline(np.array([[0.0, 0.0], [3.0, 0.0], [19.0, 0.0]]), 20)
    np.testing.assert_allclose(out[:, 0], np.arange(20.0), atol=1e-12)


def test_zero_length_polyline_repeats_the_point_without_nan():
    out = resample_polyline(np.array([[1.0, 2.0], [1.0, 2.0], [1.0, 2.0]]), 5)
    np.testing.assert_array_equal(out, np.tile([1.0, 2.0], (5, 1)))
    out = resample_polyline(np.array([[1.0, 2.0]]), 3)
    assert out.shape == (3, 2)


def test_bad_polylines_are_rejected():
    with pytest.raises(ValueError, match="NaN"):
        resample_polyline(np.array([[0.0, np.nan], [1.0, 1.0]]))
    with pytest.raises(ValueError, match="shape"):
        resample_polyline(np.zeros((0, 2)))
    with pytest.raises(ValueError, match="num"):
        resample_polyline(np.zeros((3, 2)), 1)


def test_open_line_variants_are_itself_and_its_reversal_then_padding():
    line = np.array([[0.0, -20.0], [0.0, 20.0]])
    var = ordering_variants(line, num=20)
    assert var.shape == (19, 20, 2)
    np.testing.assert_allclose(var[0, :, 1], np.linspace(-20, 20, 20))
    np.testing.assert_allclose(var[1], var[0][::-1])
    assert np.all(var[2:] == PAD_VALUE)


def test_centerline_keeps_its_direction_only():
    line = np.array([[0.0, -20.0], [0.0, 20.0]])
    var = ordering_variants(line, num=20, directed=True)
    assert var[0, 0, 1] == -20.0 and np.all(var[1:] == PAD_VALUE)


@pytest.mark.parametrize("pattern", ["resampled", "v2"])
def test_closed_ring_variants_are_cyclic_shifts_of_the_same_ring(pattern):
    square = np.array([[0, 0], [0, 4], [4, 4], [4, 0], [0, 0]], dtype=np.float64)
    assert is_closed(square)
    var = ordering_variants(square, num=20, pattern=pattern)
    valid = var[~np.all(var == PAD_VALUE, axis=(1, 2))]
    assert len(valid) == (19 if pattern == "resampled" else 4)
    for v in valid:
        np.testing.assert_allclose(v[0], v[-1], atol=1e-12)  # each variant is closed
        assert np.all(
            np.isclose(v[:, 0], 0) | np.isclose(v[:, 0], 4) | np.isclose(v[:, 1], 0) | np.isclose(v[:, 1], 4)
        )  # on the square's outline
    starts = {tuple(np.round(v[0], 9)) for v in valid}
    assert len(starts) == len(valid)  # all different starting points
    if pattern == "resampled":
        # shift k starts at sample k of the unshifted ring
        np.testing.assert_allclose(valid[3][:-1], np.roll(valid[0][:-1], -3, axis=0))


def test_v2_pattern_subsamples_many_vertices_with_the_rng():
    ring = np.column_stack([np.cos(np.linspace(0, 2 * np.pi, 41)), np.sin(np.linspace(0, 2 * np.pi, 41))])
    ring[-1] = ring[0]
    a = ordering_variants(ring, pattern="v2", rng=np.random.default_rng(1))
    b = ordering_variants(ring, pattern="v2", rng=np.random.default_rng(1))
    assert a.shape == (19, 20, 2) and not np.any(a == PAD_VALUE)
    np.testing.assert_array_equal(a, b)


def test_clamping_to_the_patch():
    var = ordering_variants(np.array([[-40.0, 0.0], [40.0, 70.0]]), num=5)
    assert var[0, 0, 0] == -15.0 and var[0, -1, 0] == 15.0 and var[0, -1, 1] == 30.0


def test_targets_skip_unknown_classes_and_stack():
    vectors = [
        ("divider", np.array([[0.0, 0.0], [0.0, 5.0]])),
        ("centerline", np.array([[1.0, 0.0], [1.0, 5.0]])),
        ("stop_line", np.array([[2.0, 0.0], [2.0, 5.0]])),
    ]
    labels, fixed, shifts = fixed_point_targets(vectors, CLASS_IDS, num=10)
    assert labels.tolist() == [CLASS_IDS["divider"], CLASS_IDS["centerline"]]
    assert fixed.shape == (2, 10, 2) and shifts.shape == (2, 9, 10, 2)
    labels, fixed, shifts = fixed_point_targets([], CLASS_IDS, num=10)
    assert labels.shape == (0,) and fixed.shape == (0, 10, 2) and shifts.shape == (0, 9, 10, 2)
