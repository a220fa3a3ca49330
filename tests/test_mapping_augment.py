"""The BEV mirror keeps geometry consistent: mirrored GT seen through the mirrored ``lidar2img`` lands
on the same pixels at the same depths, the BEV target is the target of the mirrored GT, and
padding rows of the ordering variants stay padding."""

from __future__ import annotations

import numpy as np
import torch

from nuav2.mapping.augment import mirror
from nuav2.mapping.config import MapModelConfig
from nuav2.mapping.targets import bev_targets
from nuav2.maptr.fixed_points import PAD_VALUE, fixed_point_targets

CFG = MapModelConfig()
VECTORS = [
    ("divider", np.array([[-3.0, -20.0], [-2.0, 25.0]])),
    ("ped_crossing", np.array([[2.0, 10.0], [8.0, 10.0], [8.0, 14.0], [2.0, 14.0], [2.0, 10.0]])),
]


def _hom(p: torch.Tensor) -> torch.Tensor:
    """Points on the ground 1.8 m below LIDAR_TOP, homogeneous."""
    return torch.cat(
        [p, torch.full((len(p), 1), -1.8, dtype=p.dtype), torch.ones(len(p), 1, dtype=p.dtype)], 1
    )


def _batch(signs_list):
    ids = {c: i for i, c in enumerate(CFG.classes)}
    labels, _, shifts = fixed_point_targets(VECTORS, ids, CFG.num_points, half_extent_xy=CFG.half_extent_xy)
    gen = torch.Generator().manual_seed(1)
    l2i = torch.randn(len(signs_list), 6, 4, 4, generator=gen)
    l2i[..., 3, :] = torch.tensor([0.0, 0.0, 0.0, 1.0])
    return {
        "lidar2img": l2i,
        "gt_labels": [torch.from_numpy(labels)] * len(signs_list),
        "gt_shifts": [torch.from_numpy(shifts).float()] * len(signs_list),
        "bev_target": torch.from_numpy(np.stack([bev_targets(VECTORS, CFG)] * len(signs_list))),
    }


def test_mirrored_gt_projects_to_the_same_pixels():
    signs = torch.tensor([[1.0, 1.0], [-1.0, 1.0], [1.0, -1.0], [-1.0, -1.0]])
    batch = _batch(signs)
    out = mirror(batch, signs)
    for b in range(len(signs)):
        before, after = batch["gt_shifts"][b], out["gt_shifts"][b]
        real = before > PAD_VALUE / 2
        assert torch.equal(after[~real], before[~real])  # padding stays padding
        pts = before[real.all(-1)][:, None, :].reshape(-1, 2).double()
        new = after[real.all(-1)][:, None, :].reshape(-1, 2).double()
        # the same points, in one order (a ring under one mirrored axis comes reversed)
        pts = pts[np.lexsort((pts * signs[b].double()).numpy().round(6).T)]
        new = new[np.lexsort(new.numpy().round(6).T)]
        a = _hom(pts) @ batch["lidar2img"][b].double().transpose(-1, -2)
        c = _hom(new) @ out["lidar2img"][b].double().transpose(-1, -2)
        torch.testing.assert_close(a, c)
        mirrored = [(cls, p * signs[b].numpy()) for cls, p in VECTORS]
        got, want = out["bev_target"][b].float(), torch.from_numpy(bev_targets(mirrored, CFG)).float()
        # equal up to the rasteriser's choice of pixel at exact half-cell ties
        near = torch.nn.functional.max_pool2d
        assert (got <= near(want, 3, 1, 1)).all() and (want <= near(got, 3, 1, 1)).all()
        assert abs(float(got.sum() - want.sum())) <= 0.05 * float(want.sum())
    assert torch.equal(out["gt_labels"][0], batch["gt_labels"][0])


def _signed_area(ring: torch.Tensor) -> float:
    x, y = ring[:, 0].double(), ring[:, 1].double()
    return 0.5 * float((x * y.roll(-1) - x.roll(-1) * y).sum())


def test_one_mirrored_axis_keeps_rings_clockwise_and_their_loss_zero():
    """Mirroring one axis reverses a ring's direction; the GT rings are clockwise and their variants
    only cyclic shifts, so without re-reversing them the right shape traced clockwise costs a loss."""
    from nuav2.mapping.losses import LossConfig, normalise_points, set_loss

    signs = torch.tensor([[1.0, 1.0], [-1.0, 1.0], [1.0, -1.0], [-1.0, -1.0]])
    batch = _batch(signs)
    out = mirror(batch, signs)
    ring = CFG.classes.index("ped_crossing")
    k = int((batch["gt_labels"][0] == ring).nonzero()[0])
    turn = np.sign(_signed_area(batch["gt_shifts"][0][k, 0]))  # MapTR's GT: clockwise (-1)
    for b in range(len(signs)):
        variants = out["gt_shifts"][b][k]
        real = (variants > PAD_VALUE / 2).all(-1).all(-1)
        assert all(np.sign(_signed_area(v)) == turn for v in variants[real]), signs[b]
        # the mirrored ring, traced clockwise from its mirrored first point, matches a variant: loss 0
        mirrored = torch.from_numpy(fixed_point_targets(
            [(c, p * signs[b].numpy()) for c, p in VECTORS], {c: i for i, c in enumerate(CFG.classes)},
            CFG.num_points, half_extent_xy=CFG.half_extent_xy)[1]).float()
        if np.sign(_signed_area(mirrored[k])) != turn:
            mirrored[k] = mirrored[k].flip(0)
        logits = torch.full((1, len(VECTORS), len(CFG.classes)), -20.0)
        logits[0, torch.arange(len(VECTORS)), batch["gt_labels"][b]] = 20.0
        loss = set_loss([(logits, normalise_points(mirrored, CFG)[None])], [batch["gt_labels"][b]],
                        [out["gt_shifts"][b]], CFG, LossConfig())
        assert float(loss["pts"]) < 1e-6, (signs[b], float(loss["pts"]))
