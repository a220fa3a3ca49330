"""Polyline resampling by arc length, as MapTR's evaluator does before computing chamfer distances.

MapTR resamples every GT line (and every prediction whose vertex count differs from the target)
to ``n`` points at ``np.linspace(0, length, n)`` along the line with shapely's ``interpolate``.
This module does the same for many lines at once in one numba kernel, using the same
arithmetic as GEOS (sequential segment-length sums, ``p0 + frac * (p1 - p0)``), so results
match shapely to the last few ulps.
"""

from __future__ import annotations

import numba
import numpy as np


def pack_polylines(lines: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Concatenate (N_i, 2) polylines into flat ``coords`` (sum N_i, 2) and CSR ``offsets`` (n + 1,)."""
    offsets = np.zeros(len(lines) + 1, dtype=np.int64)
    if lines:
        offsets[1:] = np.cumsum([len(line) for line in lines])
        coords = np.ascontiguousarray(np.concatenate(lines, axis=0), dtype=np.float64)
    else:
        coords = np.zeros((0, 2), dtype=np.float64)
    return coords.reshape(-1, 2), offsets


@numba.njit(cache=True, parallel=True)
def _resample_kernel(coords: np.ndarray, offsets: np.ndarray, n_points: int, out: np.ndarray) -> None:
    for k in numba.prange(offsets.shape[0] - 1):
        start = offsets[k]
        stop = offsets[k + 1]
        # Total arc length, summed sequentially like GEOS's LineString::getLength.
        length = 0.0
        for v in range(start + 1, stop):
            dx = coords[v, 0] - coords[v - 1, 0]
            dy = coords[v, 1] - coords[v - 1, 1]
            length += np.sqrt(dx * dx + dy * dy)
        if stop - start == 1 or length <= 0.0:
            for i in range(n_points):
                out[k, i, 0] = coords[start, 0]
                out[k, i, 1] = coords[start, 1]
            continue
        # Walk the segments once; seg_start is the same sequential partial sum.
        v = start
        seg_start = 0.0
        dx = coords[v + 1, 0] - coords[v, 0]
        dy = coords[v + 1, 1] - coords[v, 1]
        seg_len = np.sqrt(dx * dx + dy * dy)
        step = length / (n_points - 1)
        for i in range(n_points):
            # np.linspace(0, length, n): step * i, with the last sample exactly at `length`.
            s = length if i == n_points - 1 else step * i
            if s >= length:
                out[k, i, 0] = coords[stop - 1, 0]
                out[k, i, 1] = coords[stop - 1, 1]
                continue
            # First segment whose end lies strictly beyond s (GEOS walks segments the same way).
            while v < stop - 2 and seg_start + seg_len <= s:
                seg_start += seg_len
                v += 1
                dx = coords[v + 1, 0] - coords[v, 0]
                dy = coords[v + 1, 1] - coords[v, 1]
                seg_len = np.sqrt(dx * dx + dy * dy)
            x0 = coords[v, 0]
            y0 = coords[v, 1]
            if seg_len > 0.0:
                frac = min((s - seg_start) / seg_len, 1.0)
                out[k, i, 0] = x0 + frac * (coords[v + 1, 0] - x0)
                out[k, i, 1] = y0 + frac * (coords[v + 1, 1] - y0)
            else:
                out[k, i, 0] = x0
                out[k, i, 1] = y0


@numba.njit(cache=True, parallel=True)
def _bbox_kernel(pts: np.ndarray, out: np.ndarray) -> None:
    for k in numba.prange(pts.shape[0]):
        x0 = x1 = pts[k, 0, 0]
        y0 = y1 = pts[k, 0, 1]
        for i in range(1, pts.shape[1]):
            x0 = min(x0, pts[k, i, 0])
            x1 = max(x1, pts[k, i, 0])
            y0 = min(y0, pts[k, i, 1])
            y1 = max(y1, pts[k, i, 1])
        out[k, 0] = x0
        out[k, 1] = y0
        out[k, 2] = x1
        out[k, 3] = y1


def bboxes(pts: np.ndarray) -> np.ndarray:
    """Axis-aligned boxes (n, 4) = (xmin, ymin, xmax, ymax) of (n, m, 2) point sets (m >= 1)."""
    pts = np.ascontiguousarray(pts, dtype=np.float64)
    out = np.zeros((len(pts), 4), dtype=np.float64)
    if len(pts):
        _bbox_kernel(pts, out)
    return out


def resample_packed(coords: np.ndarray, offsets: np.ndarray, n_points: int = 100) -> np.ndarray:
    """Resample packed polylines (see :func:`pack_polylines`) to (n_lines, n_points, 2) float64.

    A zero-length line (all vertices equal) becomes ``n_points`` copies of its first vertex,
    as shapely's ``interpolate`` returns. Every line needs at least one vertex.
    """
    if n_points < 2:
        raise ValueError(f"n_points must be >= 2, got {n_points}")
    coords = np.ascontiguousarray(coords, dtype=np.float64).reshape(-1, 2)
    offsets = np.ascontiguousarray(offsets, dtype=np.int64)
    if len(offsets) > 1 and np.any(np.diff(offsets) < 1):
        raise ValueError("every polyline needs at least one vertex")
    out = np.empty((len(offsets) - 1, n_points, 2), dtype=np.float64)
    if len(out):
        _resample_kernel(coords, offsets, n_points, out)
    return out


def resample_polylines(lines: list[np.ndarray], n_points: int = 100) -> np.ndarray:
    """Resample each (N_i, 2) polyline to ``n_points`` evenly spaced by arc length -> (n, n_points, 2)."""
    coords, offsets = pack_polylines([np.asarray(line, dtype=np.float64).reshape(-1, 2) for line in lines])
    return resample_packed(coords, offsets, n_points)
