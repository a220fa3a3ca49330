"""The drivable-area mask PNG: a pixel is drivable exactly when its centre lies in a polygon."""

from __future__ import annotations

import numpy as np
import shapely
from shapely.geometry import Polygon

from nuav2.nuscenes_db.map_mask import rasterize_polygons


def test_rasterization_oracle():
    ring = Polygon([(2, 2), (18, 2), (18, 12), (2, 12)], [[(6, 5), (12, 5), (12, 9), (6, 9)]])
    island = Polygon([(8, 6), (10, 6), (10, 8), (8, 8)])  # inside the hole: must survive
    mask = rasterize_polygons([island, ring], (20.0, 15.0), 0.1)
    assert mask.shape == (150, 200)
    rows, cols = np.mgrid[0:150, 0:200]
    x, y = cols * 0.1, (150 - rows) * 0.1  # MapMask's pixel -> global convention
    union = shapely.union(ring, island)
    np.testing.assert_array_equal(mask == 255, shapely.intersects_xy(union, x, y))  # every pixel


def test_a_pixel_is_drivable_exactly_when_its_centre_is_in_a_polygon():
    """cv2's fill also marks every pixel an edge crosses (areas grew by up to 0.1 m); random polygons,
    with holes, slivers and parts off the canvas, must match the centre test on every pixel."""
    rng = np.random.default_rng(0)
    rows, cols = np.mgrid[0:150, 0:200]
    x, y = cols * 0.1, (150 - rows) * 0.1
    tested = 0
    for _ in range(200):
        centre, radius = rng.uniform(-2, 22, 2), rng.uniform(0.05, 8)
        angle = np.sort(rng.uniform(0, 2 * np.pi, rng.integers(3, 12)))
        reach = radius * rng.uniform(0.3, 1, len(angle))
        ring = np.c_[centre[0] + reach * np.cos(angle), centre[1] + reach * np.sin(angle)]
        holes = [centre + (ring - centre) * 0.2] if rng.random() < 0.4 else []
        poly = Polygon(ring, holes).buffer(0)
        if poly.geom_type != "Polygon":
            continue
        tested += 1
        mask = rasterize_polygons([poly], (20.0, 15.0), 0.1)
        np.testing.assert_array_equal(mask == 255, shapely.intersects_xy(poly, x, y))
    assert tested > 150
    square = Polygon([(10.03, 10.03), (19.97, 10.03), (19.97, 19.97), (10.03, 19.97)])
    assert (rasterize_polygons([square], (30.0, 30.0)) == 255).sum() == 99 * 99  # was 101 x 101
