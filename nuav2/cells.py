"""Which points share a grid cell: voxel downsampling and per-cell counts, one 1-D sort instead of a row sort.

``np.unique(keys, axis=0)`` sorts (N, D) integer rows through a structured view, about 15x slower than
sorting one int64 per point (1.3 s against 0.08 s for the 0.5 M static LiDAR points of a 15 s log).
Packing the shifted cell indices into one int64, most significant axis first, keeps the rows'
lexicographic order, so :func:`unique_cells` returns exactly what the row sort returns.
"""

from __future__ import annotations

import numpy as np

from nuav2.geometry import F64

_MAX_PACKED = 1 << 62


def cell_indices(points: F64, cell_m: float, shift: float = 0.0) -> np.ndarray:
    """(N, D) int64 cell of each point in a grid of ``cell_m`` cells moved by ``shift`` cells."""
    if not cell_m > 0:
        raise ValueError(f"cell size must be > 0, got {cell_m}")
    return np.floor(np.asarray(points, np.float64) / cell_m + shift).astype(np.int64)


def unique_cells(points: F64, cell_m: float, shift: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(first (M,), inverse (N,), counts (M,)) of the occupied cells, sorted as
    ``np.unique(cell_indices(...), axis=0, return_index=True, return_inverse=True, return_counts=True)``:
    ``first`` is each cell's first point, ``inverse`` each point's cell."""
    k = cell_indices(points, cell_m, shift)
    if len(k) == 0:
        empty = np.zeros(0, np.int64)
        return empty, empty, empty
    k = k.reshape(len(k), -1)
    k = k - k.min(axis=0)
    span = k.max(axis=0) + 1
    if np.prod([float(s) for s in span]) >= _MAX_PACKED:  # a huge extent: rows, slower but exact
        _, first, inverse, counts = np.unique(k, axis=0, return_index=True, return_inverse=True,
                                              return_counts=True)
        return first, inverse.reshape(-1), counts
    key = k[:, 0].copy()
    for d in range(1, k.shape[1]):
        key = key * span[d] + k[:, d]
    _, first, inverse, counts = np.unique(key, return_index=True, return_inverse=True, return_counts=True)
    return first, inverse.reshape(-1), counts


def cell_means(values: np.ndarray, inverse: np.ndarray, counts: np.ndarray) -> F64:
    """(M, D) mean of the (N, D) ``values`` per cell (:func:`unique_cells`' ``inverse`` and ``counts``)."""
    values = np.asarray(values, np.float64).reshape(len(inverse), -1)
    out = np.zeros((len(counts), values.shape[1]))
    for d in range(values.shape[1]):
        out[:, d] = np.bincount(inverse, weights=values[:, d], minlength=len(counts)) / counts
    return out
