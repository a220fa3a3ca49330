"""MapTR's set loss: Hungarian matching over permutation-equivalent targets, then focal + point L1 +
edge direction, per decoder layer; plus the auxiliary dense segmentation losses.

A GT element's target is the *set* of its equivalent point orderings (both directions of a line,
every start of a ring; :mod:`nuav2.maptr.fixed_points`), so the matching cost and the point loss
take the cheapest ordering. Points are compared normalised to the patch ([0, 1]^2), as MapTR does.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F
from scipy.optimize import linear_sum_assignment

from nuav2.mapping.config import LossConfig, MapModelConfig
from nuav2.maptr.fixed_points import PAD_VALUE


def normalise_points(pts_xy: torch.Tensor, cfg: MapModelConfig) -> torch.Tensor:
    """LIDAR_TOP xy (metres) -> [0, 1]^2 over the patch (x right, y forward)."""
    hx, hy = cfg.half_extent_xy
    scale = pts_xy.new_tensor([2 * hx, 2 * hy])
    return (pts_xy + pts_xy.new_tensor([hx, hy])) / scale


def denormalise_points(pts01: torch.Tensor, cfg: MapModelConfig) -> torch.Tensor:
    hx, hy = cfg.half_extent_xy
    return pts01 * pts01.new_tensor([2 * hx, 2 * hy]) - pts01.new_tensor([hx, hy])


def focal_cost(logits: torch.Tensor, labels: torch.Tensor, alpha: float, gamma: float) -> torch.Tensor:
    """(Q, G) focal classification cost of giving each query each GT's class (DETR-style)."""
    p = logits.sigmoid()[:, labels]
    neg = (1 - alpha) * p.pow(gamma) * -(1 - p + 1e-8).log()
    pos = alpha * (1 - p).pow(gamma) * -(p + 1e-8).log()
    return pos - neg


def point_cost(
    pred: torch.Tensor, variants: torch.Tensor, valid: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Mean L1 over points of each (query, GT) pair at the GT's best ordering: (Q, G) cost and
    (Q, G) index of that ordering. ``variants`` (G, S, P, 2) normalised, ``valid`` (G, S)."""
    d = (pred[:, None, None] - variants[None]).abs().mean(dim=(-1, -2))  # (Q, G, S)
    d = d.masked_fill(~valid[None], float("inf"))
    return d.min(dim=-1)


def match(
    logits: torch.Tensor,
    pred_pts: torch.Tensor,
    labels: torch.Tensor,
    variants: torch.Tensor,
    valid: torch.Tensor,
    w: LossConfig,
) -> tuple[np.ndarray, np.ndarray, torch.Tensor]:
    """Hungarian assignment of one sample: (query indices, GT indices, chosen ordering per GT)."""
    with torch.no_grad():
        pts_c, best = point_cost(pred_pts, variants, valid)
        cost = w.cls_weight * focal_cost(logits, labels, w.focal_alpha, w.focal_gamma) + w.pts_weight * pts_c
        qi, gi = linear_sum_assignment(cost.double().numpy())
    return qi, gi, best[qi, gi]


def sigmoid_focal(logits: torch.Tensor, target: torch.Tensor, alpha: float, gamma: float) -> torch.Tensor:
    p = logits.sigmoid()
    ce = F.binary_cross_entropy_with_logits(logits, target, reduction="none")
    p_t = p * target + (1 - p) * (1 - target)
    a_t = alpha * target + (1 - alpha) * (1 - target)
    return (a_t * (1 - p_t).pow(gamma) * ce).sum()


def direction_loss(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """1 - cosine between consecutive-point edges (MapTR's PtsDirCosLoss), summed over edges."""
    pe, te = pred[:, 1:] - pred[:, :-1], target[:, 1:] - target[:, :-1]
    return (1 - F.cosine_similarity(pe, te, dim=-1, eps=1e-6)).sum()


def gt_variants(gt_shifts: torch.Tensor, cfg: MapModelConfig) -> tuple[torch.Tensor, torch.Tensor]:
    """Normalised ordering variants (G, S, P, 2) and which of them are real (not padding)."""
    valid = (gt_shifts > PAD_VALUE / 2).all(dim=-1).all(dim=-1)
    return normalise_points(gt_shifts.float(), cfg), valid


def set_loss(
    outputs: list[tuple[torch.Tensor, torch.Tensor]],
    gt_labels: list[torch.Tensor],
    gt_shifts: list[torch.Tensor],
    cfg: MapModelConfig,
    w: LossConfig,
) -> dict[str, torch.Tensor]:
    """Matching loss summed over decoder layers; each term normalised by the number of GT elements."""
    n_gt = max(1, sum(len(x) for x in gt_labels))
    total = {"cls": 0.0, "pts": 0.0, "dir": 0.0}
    variants = [gt_variants(s, cfg) for s in gt_shifts]
    for logits, pts in outputs:
        for b in range(len(gt_labels)):
            target_cls = torch.zeros_like(logits[b])
            labels = gt_labels[b]
            if len(labels):
                var, valid = variants[b]
                qi, gi, order = match(logits[b], pts[b], labels, var, valid, w)
                target_cls[qi, labels[gi]] = 1.0
                target_pts = var[gi, order]
                total["pts"] = total["pts"] + (pts[b, qi] - target_pts).abs().mean(dim=-1).sum()
                total["dir"] = total["dir"] + direction_loss(pts[b, qi], target_pts)
            total["cls"] = total["cls"] + sigmoid_focal(logits[b], target_cls, w.focal_alpha, w.focal_gamma)
    return {
        "cls": w.cls_weight * total["cls"] / n_gt,
        "pts": w.pts_weight * total["pts"] / n_gt,
        "dir": w.dir_weight * total["dir"] / n_gt,
    }


def dense_loss(logits: torch.Tensor, target: torch.Tensor, valid: torch.Tensor | None = None) -> torch.Tensor:
    """Per-pixel binary cross-entropy of line masks, positives up-weighted (lines are thin)."""
    target = target.float()
    pos_weight = logits.new_tensor(5.0)
    loss = F.binary_cross_entropy_with_logits(logits, target, pos_weight=pos_weight, reduction="none")
    if valid is not None:
        loss = loss * valid
        return loss.sum() / valid.expand_as(loss).sum().clamp(min=1.0)
    return loss.mean()


def depth_loss(depth_prob: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Cross-entropy of the lift's depth distributions (B, N, D, h, w) at pixels with a LiDAR depth
    bin (``target`` (B, N, h, w), -1 elsewhere)."""
    valid = target >= 0
    if not valid.any():
        return depth_prob.sum() * 0.0
    p = depth_prob.permute(0, 1, 3, 4, 2)[valid]  # (V, D)
    return -(p.gather(1, target[valid].long()[:, None]).clamp_min(1e-6).log()).mean()
