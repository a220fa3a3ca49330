"""Boundary GT without needles: a road polygon's corner a fraction of a millimetre off its
neighbour's edge leaves, after the union, an outline that runs out into the gap and straight back
(2.3 m at a converted synthetic T-junction), or a sliver ring metres long and under 1 mm wide."""

from __future__ import annotations

import numpy as np
import pytest
from shapely.geometry import LineString, Polygon, box

from nuav2.maptr.vectorize import contour_lines


def _turn_backs(lines, min_arm_m: float = 0.5) -> list:
    """Vertices where a line runs out (an arm over ``min_arm_m``) and turns back by over 90 deg."""
    out = []
    for line in lines:
        xy = np.asarray(line.coords)
        for a, b, c in zip(xy[:-2], xy[1:-1], xy[2:]):
            u, v = b - a, c - b
            if min(np.hypot(*u), np.hypot(*v)) > min_arm_m and u @ v < 0:
                out.append(b.tolist())
    return out


def test_a_sub_millimetre_gap_between_road_pieces_leaves_no_needle_in_the_boundary():
    # R3's bottom edge should lie on the top edge of R1 and R2; its corner sits 0.3 mm above it and
    # the edge dips under it 7.5 m further on: the union's outline ran 7.5 m into that wedge and
    # straight back (seen at a converted synthetic T-junction, there 2.3 m)
    r1, r2 = box(-10, 0, 0, 5), box(0, 0, 10, 5)
    r3 = Polygon([(-5, 5.0003), (5, 4.9999), (5, 10), (-5, 10)])
    clean = Polygon([(-5, 5), (5, 5), (5, 10), (-5, 10)])
    got = contour_lines([r1, r2, r3], (15.0, 30.0), -0.2)
    want = contour_lines([r1, r2, clean], (15.0, 30.0), -0.2)
    assert _turn_backs(got) == [] and len(got) == len(want) == 1
    assert LineString(got[0].coords).hausdorff_distance(LineString(want[0].coords)) < 1e-3


def test_drop_needles_keeps_real_corners():
    from nuav2.maptr.ring_needles import drop_needles

    square = np.array([[0, 0], [0, 4], [4, 4], [4, 0], [0, 0]], float)
    assert np.array_equal(drop_needles(square), square)
    # a sharp but real spur, 5 mm wide at its base over 2 m: kept
    spur = np.array([[0, 0], [0, 4], [2, 4], [2, 4.005], [-2, 4.0025], [-2, 6], [4, 6], [4, 0], [0, 0]])
    assert np.array_equal(drop_needles(spur), spur)
    # the same spur 0.1 mm wide is a gap in the data: its two tip corners go, and nothing else
    thin = spur.copy()
    thin[3, 1], thin[4, 1] = 4.0001, 4.00005
    assert np.array_equal(drop_needles(thin), np.delete(thin, [2, 3], axis=0))


def test_a_needle_sampled_along_its_length_is_cut_whole():
    """A gap along a densely sampled road edge: each side of the needle has 50 vertices."""
    from nuav2.maptr.ring_needles import drop_needles

    square = np.array([[0, 0], [0, 10], [10, 10], [10, 0]], float)
    out = np.c_[np.linspace(10, 30, 51)[1:], np.full(50, 5.0)]
    back = np.c_[np.linspace(30, 10, 51)[1:-1], 5.0 - np.linspace(2e-4, 1e-4, 49)]
    ring = np.vstack([square[:3], [10, 5.0], out, back, [10, 5.0 - 1e-4], square[3:], square[:1]])
    got = drop_needles(ring)
    assert got[:, 0].max() == 10.0 and Polygon(got).area == pytest.approx(100.0)


def test_sliver_rings_between_road_pieces_do_not_become_boundaries():
    """Road quads whose shared corners are up to 0.5 mm apart: the union encloses holes under
    1 mm wide and metres long, which came out as closed boundary rings (a few clockwise)."""
    rng = np.random.default_rng(0)
    slivers = rings = 0
    for _ in range(300):
        nx, ny = rng.integers(2, 4), rng.integers(2, 4)
        xs, ys = np.cumsum(rng.uniform(2, 8, nx + 1)), np.cumsum(rng.uniform(2, 8, ny + 1))
        pieces = []
        for i in range(nx):
            for j in range(ny):
                if rng.random() < 0.3:
                    continue
                c = np.array([[xs[i], ys[j]], [xs[i + 1], ys[j]], [xs[i + 1], ys[j + 1]], [xs[i], ys[j + 1]]])
                c = c + rng.uniform(-5e-4, 5e-4, c.shape) * (rng.random(c.shape) < 0.5)
                c -= [(xs[0] + xs[-1]) / 2, (ys[0] + ys[-1]) / 2]
                if Polygon(c).is_valid:
                    pieces.append(Polygon(c))
        for line in contour_lines(pieces, (30.0, 30.0), -0.2) if pieces else []:
            if line.is_closed:
                rings += 1
                slivers += 2 * Polygon(line.coords).area / line.length < 1e-3
    assert rings > 0 and slivers == 0
