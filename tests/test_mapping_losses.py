"""The set loss: normalisation round trip, the cheapest ordering wins the point cost, Hungarian
matching pairs each GT with its prediction, a perfect prediction costs (almost) nothing, and
decoding gives MapTR's top-k (query x class) vectors in metres."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from nuav2.mapping.config import LossConfig, MapModelConfig
from nuav2.mapping.losses import (
    denormalise_points,
    dense_loss,
    gt_variants,
    match,
    normalise_points,
    point_cost,
    set_loss,
)
from nuav2.mapping.predict import decode
from nuav2.maptr.fixed_points import fixed_point_targets

CFG = MapModelConfig()
W = LossConfig()
IDS = {c: i for i, c in enumerate(CFG.classes)}


def _targets(vectors):
    labels, fixed, shifts = fixed_point_targets(
        vectors, IDS, CFG.num_points, half_extent_xy=CFG.half_extent_xy
    )
    return torch.from_numpy(labels), torch.from_numpy(fixed).float(), torch.from_numpy(shifts).float()


VECTORS = [
    ("divider", np.array([[-3.0, -20.0], [-3.0, 25.0]])),
    ("ped_crossing", np.array([[2.0, 10.0], [8.0, 10.0], [8.0, 14.0], [2.0, 14.0], [2.0, 10.0]])),
    ("centerline", np.array([[1.5, -28.0], [1.5, 0.0], [6.0, 20.0]])),
]


def test_normalise_round_trip_and_range():
    xy = torch.tensor([[-15.0, -30.0], [15.0, 30.0], [0.0, 0.0], [3.2, -7.7]], dtype=torch.float64)
    n = normalise_points(xy, CFG)
    torch.testing.assert_close(n[:3], torch.tensor([[0.0, 0.0], [1.0, 1.0], [0.5, 0.5]], dtype=torch.float64))
    torch.testing.assert_close(denormalise_points(n, CFG), xy)


def test_point_cost_takes_the_cheapest_ordering():
    labels, fixed, shifts = _targets(VECTORS[:1])
    var, valid = gt_variants(shifts, CFG)
    assert valid[0].sum() == 2  # an open line: itself and its reversal
    reversed_pred = normalise_points(fixed[0].flip(0), CFG)[None]
    cost, best = point_cost(reversed_pred, var, valid)
    assert float(cost[0, 0]) < 1e-6 and int(best[0, 0]) == 1
    # a ring: any start point is the same element
    labels, fixed, shifts = _targets(VECTORS[1:2])
    var, valid = gt_variants(shifts, CFG)
    rolled = torch.cat([fixed[0, 7:-1], fixed[0, :8]])  # start at the 8th point, closed again
    cost, _ = point_cost(normalise_points(rolled, CFG)[None], var, valid)
    assert float(cost[0, 0]) < 1e-6


def test_match_pairs_each_gt_with_its_prediction_and_perfect_predictions_cost_little():
    labels, fixed, shifts = _targets(VECTORS)
    var, valid = gt_variants(shifts, CFG)
    Q = 5
    pts = torch.full((Q, CFG.num_points, 2), 0.5)
    pts[3] = normalise_points(fixed[0].flip(0), CFG)  # GT 0, reversed
    pts[0] = normalise_points(fixed[2], CFG)  # GT 2 (a centerline keeps its direction)
    pts[4] = normalise_points(fixed[1], CFG)  # GT 1
    logits = torch.full((Q, len(CFG.classes)), -6.0)
    for q, g in ((3, 0), (0, 2), (4, 1)):
        logits[q, labels[g]] = 6.0
    qi, gi, order = match(logits, pts, labels, var, valid, W)
    assert dict(zip(gi.tolist(), qi.tolist())) == {0: 3, 1: 4, 2: 0}
    assert order.tolist()[list(gi).index(0)] == 1  # GT 0 matched in reversed order
    loss = set_loss([(logits[None], pts[None])], [labels], [shifts], CFG, W)
    assert float(loss["pts"]) < 1e-6 and float(loss["dir"]) < 1e-6
    # the same queries 1 m off in x cost more
    moved = pts.clone()
    moved[[0, 3, 4], :, 0] += 1.0 / 30.0
    worse = set_loss([(logits[None], moved[None])], [labels], [shifts], CFG, W)
    assert float(worse["pts"]) > 0.1 and float(worse["cls"]) == float(loss["cls"])


def test_set_loss_without_gt_only_pushes_scores_down():
    logits = torch.zeros(1, 4, len(CFG.classes), requires_grad=True)
    pts = torch.full((1, 4, CFG.num_points, 2), 0.5)
    loss = set_loss(
        [(logits, pts)],
        [torch.zeros(0, dtype=torch.int64)],
        [torch.zeros(0, CFG.num_points - 1, CFG.num_points, 2)],
        CFG,
        W,
    )
    assert float(loss["pts"]) == 0.0
    loss["cls"].backward()
    assert (logits.grad > 0).all()  # gradient descent lowers every score


def test_dense_loss_ignores_masked_pixels():
    logits = torch.tensor([[0.0, 10.0], [-10.0, 0.0]])
    target = torch.tensor([[0, 0], [1, 0]], dtype=torch.uint8)
    mask_bad = torch.tensor([[0.0, 1.0], [1.0, 0.0]])
    mask_good = torch.tensor([[1.0, 0.0], [0.0, 1.0]])
    assert float(dense_loss(logits, target, mask_bad)) > 5.0
    assert float(dense_loss(logits, target, mask_good)) < 1.0


def test_decode_takes_top_k_query_class_pairs_in_metres():
    logits = torch.full((3, len(CFG.classes)), -5.0)
    logits[1, 2] = 3.0
    logits[2, 0] = 1.0
    logits[2, 3] = 2.0
    pts = torch.rand(3, CFG.num_points, 2)
    out = decode(logits, pts, CFG, top_k=3)
    assert [(c, round(s, 4)) for c, _, s in out] == [
        (CFG.classes[2], round(float(torch.sigmoid(torch.tensor(3.0))), 4)),
        (CFG.classes[3], round(float(torch.sigmoid(torch.tensor(2.0))), 4)),
        (CFG.classes[0], round(float(torch.sigmoid(torch.tensor(1.0))), 4)),
    ]
    np.testing.assert_allclose(out[0][1], denormalise_points(pts[1], CFG).double().numpy(), atol=1e-6)
    np.testing.assert_allclose(out[1][1], out[2][1])  # one query can yield several classes


def test_depth_loss_is_cross_entropy_at_pixels_with_lidar():
    from nuav2.mapping.losses import depth_loss

    D = 5
    target = torch.tensor([[[[2, -1], [-1, 0]]]])  # (B=1, N=1, h=2, w=2)
    uniform = torch.full((1, 1, D, 2, 2), 1.0 / D)
    assert float(depth_loss(uniform, target)) == pytest.approx(np.log(D), rel=1e-6)
    sharp = torch.zeros(1, 1, D, 2, 2)
    sharp[0, 0, 2, 0, 0] = 1.0
    sharp[0, 0, 0, 1, 1] = 1.0
    sharp[0, 0, 4, 0, 1] = 1.0  # a pixel without LiDAR: whatever it says costs nothing
    assert float(depth_loss(sharp, target)) == pytest.approx(0.0, abs=1e-6)
    assert float(depth_loss(uniform, torch.full_like(target, -1))) == 0.0
