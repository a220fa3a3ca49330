"""Fixed-point-count map instances and their equivalent orderings (MapTR's permutation targets).

MapTR predicts every map element as ``num_points`` points. A closed shape (crossing ring)
has no natural start, and an open line (divider, boundary) no natural direction, so the
training target of one instance is the set of all equivalent point orderings; the matcher
takes the cheapest. This module turns raw polylines into those sets:

- closed polyline (first point == last point) -> every cyclic shift of the ring;
- open polyline -> itself and its reversal;
- centerline -> itself only (its direction is the driving direction, which is information).

Rows beyond the available variants are filled with ``PAD_VALUE`` (MapTR's -10000), points
are clamped to the patch half-extents like MapTR's ``LiDARInstanceLines``.
"""

from __future__ import annotations

import numpy as np

from nuav2.geometry import F64

PAD_VALUE = -10000.0
CLOSED_TOL_M = 1e-6


def _as_polyline(pts: np.ndarray) -> F64:
    arr = np.asarray(pts, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] < 2 or len(arr) == 0:
        raise ValueError(f"polyline must be (N>=1, 2) points, got shape {arr.shape}")
    arr = arr[:, :2]
    if not np.all(np.isfinite(arr)):
        raise ValueError("polyline contains NaN/Inf")
    return arr


def polyline_length(pts: np.ndarray) -> float:
    arr = _as_polyline(pts)
    return float(np.sum(np.linalg.norm(np.diff(arr, axis=0), axis=1)))


def is_closed(pts: np.ndarray, tol: float = CLOSED_TOL_M) -> bool:
    """A ring: at least 4 points (3 distinct) and the last equals the first."""
    arr = _as_polyline(pts)
    return len(arr) >= 4 and bool(np.all(np.abs(arr[0] - arr[-1]) <= tol))


def resample_polyline(pts: np.ndarray, num: int = 20) -> F64:
    """``num`` points evenly spaced by arc length, first and last kept exactly.

    A zero-length polyline (one point, or repeated points) gives ``num`` copies of its
    first point rather than NaN from a 0/0 interpolation.
    """
    if num < 2:
        raise ValueError(f"num must be >= 2, got {num}")
    arr = _as_polyline(pts)
    seg = np.linalg.norm(np.diff(arr, axis=0), axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    total = cum[-1]
    if not total > 0:
        return np.repeat(arr[:1], num, axis=0)
    keep = np.concatenate([[True], seg > 0])  # np.interp needs increasing x
    targets = np.linspace(0.0, total, num)
    out = np.column_stack([np.interp(targets, cum[keep], arr[keep, d]) for d in range(2)])
    out[0], out[-1] = arr[0], arr[-1]
    return out


def _cyclic_shifts_resampled(ring: F64, num: int) -> F64:
    """All ``num - 1`` rings that start at a different resampled point (each closed again)."""
    pts = resample_polyline(ring, num)[:-1]  # num - 1 distinct points around the ring
    m = num - 1
    idx = (np.arange(m)[:, None] + np.arange(m + 1)[None, :]) % m  # row k: k, k+1, ..., k (closed again)
    return pts[idx]


def _cyclic_shifts_v2(ring: F64, num: int, max_variants: int, rng: np.random.Generator) -> F64:
    """MapTRv2's ``v2`` pattern: start the ring at each *source* vertex, then resample;
    more than ``max_variants`` shifts are subsampled at random (hence the rng)."""
    verts = ring[:-1]
    shifts = []
    for k in range(len(verts)):
        rolled = np.roll(verts, k, axis=0)
        shifts.append(resample_polyline(np.vstack([rolled, rolled[:1]]), num))
    out = np.stack(shifts)
    if len(out) > max_variants:
        out = out[np.sort(rng.choice(len(out), max_variants, replace=False))]
    return out


def ordering_variants(
    pts: np.ndarray,
    num: int = 20,
    max_variants: int | None = None,
    directed: bool = False,
    pattern: str = "resampled",
    half_extent_xy: tuple[float, float] | None = (15.0, 30.0),
    rng: np.random.Generator | None = None,
) -> F64:
    """(max_variants, num, 2) equivalent orderings of one instance, padded with ``PAD_VALUE``.

    ``directed`` (centerlines) keeps only the original order. ``pattern`` picks how a closed
    ring is shifted: ``"resampled"`` (resample once, then the ``num - 1`` cyclic shifts of the
    samples; deterministic) or ``"v2"`` (MapTRv2: shift the source vertices, resample each).
    ``max_variants`` defaults to ``num - 1`` (19 for 20 points), as in MapTR.
    """
    if pattern not in ("resampled", "v2"):
        raise ValueError(f"unknown shift pattern {pattern!r}; use 'resampled' or 'v2'")
    max_variants = num - 1 if max_variants is None else max_variants
    if max_variants < 1:
        raise ValueError(f"max_variants must be >= 1, got {max_variants}")
    arr = _as_polyline(pts)
    if directed:
        variants = resample_polyline(arr, num)[None]
    elif is_closed(arr):
        if pattern == "v2":
            variants = _cyclic_shifts_v2(arr, num, max_variants, rng or np.random.default_rng(0))
        else:
            variants = _cyclic_shifts_resampled(arr, num)
    else:
        fwd = resample_polyline(arr, num)
        variants = np.stack([fwd, fwd[::-1]])
    variants = variants[:max_variants]
    if half_extent_xy is not None:
        hx, hy = half_extent_xy
        variants = np.stack([np.clip(variants[..., 0], -hx, hx), np.clip(variants[..., 1], -hy, hy)], -1)
    out = np.full((max_variants, num, 2), PAD_VALUE)
    out[: len(variants)] = variants
    return out


def fixed_point_targets(
    vectors: list[tuple[str, np.ndarray]],
    class_ids: dict[str, int],
    num: int = 20,
    pattern: str = "resampled",
    directed_classes: tuple[str, ...] = ("centerline",),
    half_extent_xy: tuple[float, float] | None = (15.0, 30.0),
    rng: np.random.Generator | None = None,
) -> tuple[np.ndarray, F64, F64]:
    """Labels (M,), fixed points (M, num, 2) and ordering variants (M, num-1, num, 2) of a sample.

    Classes not in ``class_ids`` are skipped (e.g. a 3-class model ignores centerlines).
    """
    labels, fixed, shifts = [], [], []
    for cls, pts in vectors:
        if cls not in class_ids:
            continue
        var = ordering_variants(pts, num, None, cls in directed_classes, pattern, half_extent_xy, rng)
        labels.append(class_ids[cls])
        fixed.append(var[0])
        shifts.append(var)
    if not labels:
        return np.zeros(0, np.int64), np.zeros((0, num, 2)), np.zeros((0, num - 1, num, 2))
    return np.array(labels, np.int64), np.stack(fixed), np.stack(shifts)
