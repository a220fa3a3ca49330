"""unique_cells returns what numpy's row sort returns (first points, each point's cell, counts), faster."""

from __future__ import annotations

import numpy as np
import pytest

from nuav2.cells import cell_indices, unique_cells


@pytest.mark.parametrize("dims, cell_m, shift, scale", [(3, 0.3, 0.0, 2000.0), (3, 0.05, 0.5, 3.0),
                                                        (2, 0.5, 0.0, 50.0), (3, 1e-12, 0.0, 1e6)])
def test_unique_cells_matches_the_row_sort(dims, cell_m, shift, scale):
    rng = np.random.default_rng(dims)
    pts = (rng.random((5000, dims)) - 0.5) * scale  # negative and positive cells, city-sized extents
    pts = np.concatenate([pts, pts[:700] + 1e-4])  # repeated cells
    rows = cell_indices(pts, cell_m, shift)
    _, first, inv, counts = np.unique(rows, axis=0, return_index=True, return_inverse=True,
                                      return_counts=True)
    got = unique_cells(pts, cell_m, shift)  # the last case's extent overflows a packed int64: the row path
    np.testing.assert_array_equal(got[0], first)
    np.testing.assert_array_equal(got[1], inv.reshape(-1))
    np.testing.assert_array_equal(got[2], counts)
    assert counts.sum() == len(pts)


def test_empty_and_bad_cell_size():
    first, inv, counts = unique_cells(np.zeros((0, 3)), 0.1)
    assert len(first) == len(inv) == len(counts) == 0
    with pytest.raises(ValueError, match="cell size"):
        unique_cells(np.zeros((2, 3)), 0.0)
