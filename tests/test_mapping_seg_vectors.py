"""Polylines traced from the BEV segmentation: a perfect segmentation of known map lines traces back to
those lines in LIDAR_TOP metres (conventions end to end), scores are the cells' probabilities, and a
branching ridge is peeled into separate paths."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from nuav2.mapping.config import MapModelConfig
from nuav2.mapping.seg_vectors import resample, seg_vectors, trace_paths
from nuav2.mapping.targets import bev_targets

CFG = MapModelConfig()
LINES = [
    ("divider", np.array([[-1.75, -25.0], [-1.75, 25.0]])),
    ("boundary", np.array([[6.0, -20.0], [6.0, 0.0], [12.0, 10.0]])),
]


def _chamfer(a: np.ndarray, b: np.ndarray) -> float:
    d = np.linalg.norm(resample(a, 100)[:, None] - resample(b, 100)[None], axis=-1)
    return max(d.min(0).mean(), d.min(1).mean())


def test_a_perfect_segmentation_traces_back_to_its_lines():
    logits = torch.from_numpy(bev_targets(LINES, CFG)).float() * 12 - 6
    out = seg_vectors(logits, CFG, threshold=0.5)
    assert sorted(c for c, _, _ in out) == ["boundary", "divider"]
    for cls, pts, score in out:
        want = dict(LINES)[cls]
        assert pts.shape == (CFG.num_points, 2)
        assert _chamfer(pts, want) < 0.5  # metres: within a cell
        assert score == pytest.approx(torch.sigmoid(torch.tensor(6.0)).item(), rel=1e-6)


def test_an_empty_or_faint_segmentation_gives_nothing():
    assert seg_vectors(torch.full((4, *CFG.bev_shape), -6.0), CFG) == []
    logits = torch.from_numpy(bev_targets(LINES, CFG)).float() * 4 - 6  # p = 0.12 on the lines
    assert seg_vectors(logits, CFG, threshold=0.2) == []


def test_a_branching_ridge_is_peeled_into_paths():
    sk = np.zeros((40, 40), bool)
    sk[5:35, 20] = True  # a vertical ridge of 30 cells
    sk[20, 21:32] = True  # a branch of 11 cells off its middle
    sk[2, 2:4] = True  # a 2-cell speck, shorter than min_cells
    paths = trace_paths(sk, min_cells=4)
    lengths = sorted(len(p) for p in paths)
    assert len(paths) == 2 and lengths[1] >= 30 and 9 <= lengths[0] <= 12
