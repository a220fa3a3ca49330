"""Remove needles from polygon outlines before they become boundary or crossing GT.

Adjacent map polygons whose shared edges do not meet exactly (a vertex a fraction of a
millimetre off its neighbour's edge: node rounding, independent survey) union into an outline
that runs metres out along the gap and straight back, or that encloses a sliver hole. MapTR
would learn either as a road boundary. A needle is a vertex where the outline turns back (more
than 90 degrees) and the triangle it spans with its neighbours is thinner than ``max_width_m``
across its longer arm; a sliver is a whole ring thinner than that.
"""

from __future__ import annotations

import numpy as np

NEEDLE_WIDTH_M = 1e-3  # outline features thinner than this are gaps in the data, not road shape


def _needles(a: np.ndarray, b: np.ndarray, c: np.ndarray, max_width_m: float) -> np.ndarray:
    """Which vertices ``b`` (rows) are needle tips between their neighbours ``a`` and ``c``."""
    ab, bc, ac = b - a, c - b, c - a
    turns_back = np.einsum("ij,ij->i", ab, bc) < 0.0
    longer = np.maximum(np.hypot(ab[:, 0], ab[:, 1]), np.hypot(bc[:, 0], bc[:, 1]))
    cross = np.abs(ab[:, 0] * ac[:, 1] - ab[:, 1] * ac[:, 0])  # twice the triangle's area
    return turns_back & (longer > 0.0) & (cross <= max_width_m * longer)


def drop_needles(ring_xy: np.ndarray, max_width_m: float = NEEDLE_WIDTH_M) -> np.ndarray:
    """The closed ring ``ring_xy`` (N, 2), first point repeated last, without its needle vertices
    (removing one can expose the next along the needle, so its neighbour is checked again); a
    ring that would fall below three corners is returned unchanged."""
    ring = np.asarray(ring_xy, dtype=np.float64)[:, :2]
    pts = ring[:-1]
    if len(pts) <= 3 or not _needles(np.roll(pts, 1, 0), pts, np.roll(pts, -1, 0), max_width_m).any():
        return ring
    kept = list(pts)
    i = 0
    while i < len(kept) and len(kept) > 3:
        a, b, c = (np.asarray(kept[j % len(kept)])[None] for j in (i - 1, i, i + 1))
        if _needles(a, b, c, max_width_m)[0]:
            del kept[i]
            i = max(i - 1, 0)
        else:
            i += 1
    # a needle whose tip straddled the ring's start: one more pass over the wrap-around
    out = np.asarray(kept)
    while len(out) > 3:
        tips = _needles(np.roll(out, 1, 0), out, np.roll(out, -1, 0), max_width_m)
        if not tips.any():
            break
        out = np.delete(out, int(np.flatnonzero(tips)[0]), axis=0)
    if len(out) < 3:
        return ring
    return np.vstack([out, out[:1]])


def is_sliver(area_m2: float, perimeter_m: float, max_width_m: float = NEEDLE_WIDTH_M) -> bool:
    """Whether a closed ring of this area and perimeter is thinner than ``max_width_m`` overall: its
    area is under that width times half its perimeter (the caller has both from its geometry)."""
    return area_m2 <= max_width_m * perimeter_m / 2.0
