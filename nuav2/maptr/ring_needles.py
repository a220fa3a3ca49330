"""Remove needles from polygon outlines before they become boundary or crossing GT.

Adjacent map polygons whose shared edges do not meet exactly (a vertex a fraction of a
millimetre off its neighbour's edge: node rounding, independent survey) union into an outline
that runs metres out along the gap and straight back. MapTR would learn that needle as a road
boundary. A needle is a vertex where the outline turns back (more than 90 degrees) and the
triangle it spans with its neighbours is thinner than ``max_width_m`` across its longer arm.
"""

from __future__ import annotations

import numpy as np

NEEDLE_WIDTH_M = 1e-3  # outline features thinner than this are gaps in the data, not road shape


def _is_needle(a: np.ndarray, b: np.ndarray, c: np.ndarray, max_width_m: float) -> bool:
    ab, bc = b - a, c - b
    if float(ab @ bc) >= 0.0:  # not turning back
        return False
    longer = max(float(np.hypot(*ab)), float(np.hypot(*bc)))
    cross = abs(float(ab[0] * (c - a)[1] - ab[1] * (c - a)[0]))  # twice the triangle's area
    return longer > 0.0 and cross <= max_width_m * longer


def drop_needles(ring_xy: np.ndarray, max_width_m: float = NEEDLE_WIDTH_M) -> np.ndarray:
    """The closed ring ``ring_xy`` (N, 2), first point repeated last, without its needle vertices
    (repeated until none is left, since removing one can expose another); a ring that would
    fall below three corners is returned unchanged."""
    pts = [p for p in np.asarray(ring_xy, dtype=np.float64)[:-1, :2]]
    changed = True
    while changed and len(pts) > 3:
        changed = False
        i = 0
        while i < len(pts) and len(pts) > 3:
            if _is_needle(pts[i - 1], pts[i], pts[(i + 1) % len(pts)], max_width_m):
                del pts[i]
                changed = True
            else:
                i += 1
    if len(pts) < 3:
        return np.asarray(ring_xy, dtype=np.float64)
    return np.vstack([pts, pts[:1]])
