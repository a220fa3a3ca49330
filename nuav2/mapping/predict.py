"""Inference: model outputs -> MapTR results (``nuscmap_results.json``), and scoring with ``nuav2 eval``.

Decoding is MapTR's (NMS-free): sigmoid scores of every (query, class) pair, the ``top_k`` best
kept, each a 20-point polyline in LIDAR_TOP metres. Scoring goes through the evaluator we ship:
:func:`score_with_nuav2_eval` runs the ``nuav2 eval`` command itself on the written file, and
:func:`score_in_process` calls the library function that command calls (for the cheap
learning curve, with the GT computed once).
"""

from __future__ import annotations

import contextlib
import io
import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from nuav2.atomic import atomic_write_json
from nuav2.mapping.config import MapModelConfig
from nuav2.mapping.data import MapTensors
from nuav2.mapping.losses import denormalise_points
from nuav2.maptr.vectorize import DEFAULT_PATCH

TOP_K = 50  # MapTR's max predictions per sample
# cell probability above which the BEV segmentation counts as a line when traced into vectors: chosen
# once, before any benchmark table, on validation worlds no benchmark uses (seeds 5000-5005) with a
# development model (0.1 / 0.15 / 0.2 / 0.3 / 0.4 / 0.5 gave mAP 4.0 / 5.2 / 6.5 / 5.5 / 4.3 / 1.6)
SEG_THRESHOLD = 0.2
Scored = list[tuple[str, np.ndarray, float]]


def decode(logits: torch.Tensor, pts01: torch.Tensor, cfg: MapModelConfig, top_k: int = TOP_K) -> Scored:
    """One sample's (Q, K) logits and (Q, P, 2) normalised points -> [(class, (P, 2) metres, score)]."""
    scores = logits.sigmoid().flatten()
    k = min(top_k, scores.numel())
    best, idx = scores.topk(k)
    n_cls = logits.shape[1]
    pts = denormalise_points(pts01, cfg).double().numpy()
    return [(cfg.classes[int(i) % n_cls], pts[int(i) // n_cls], float(s)) for s, i in zip(best, idx)]


@torch.no_grad()
def _per_sample(model, data: MapTensors, batch_size: int, decode_one) -> dict[str, Scored]:
    """``decode_one(outputs, j)`` of every keyframe of ``data`` by token, the model in eval mode."""
    was_training = model.training
    model.eval()
    out: dict[str, Scored] = {}
    try:
        for start in range(0, len(data), batch_size):
            index = list(range(start, min(len(data), start + batch_size)))
            b = data.batch(index)
            outputs = model(b["img"], b["lidar2img"], b["img_hw"])
            for j, i in enumerate(index):
                out[data.tokens[i]] = decode_one(outputs, j)
    finally:
        model.train(was_training)
    return out


def predict(model, data: MapTensors, batch_size: int = 4, top_k: int = TOP_K) -> dict[str, Scored]:
    """Predictions of the model's last decoder layer for every keyframe of ``data`` (eval mode)."""

    def one(outputs: dict, j: int) -> Scored:
        logits, pts = outputs["layers"][-1]
        return decode(logits[j], pts[j], model.cfg, top_k)

    return _per_sample(model, data, batch_size, one)


def predict_from_seg(
    model, data: MapTensors, batch_size: int = 4, threshold: float = SEG_THRESHOLD
) -> dict[str, Scored]:
    """Predictions traced from the model's BEV segmentation (:mod:`nuav2.mapping.seg_vectors`): the
    same model's second MapTR result file, scored by the same ``nuav2 eval``."""
    from nuav2.mapping.seg_vectors import seg_vectors

    return _per_sample(
        model, data, batch_size, lambda o, j: seg_vectors(o["bev_seg"][j], model.cfg, threshold)
    )


@torch.no_grad()
def bev_seg_scores(model, data: MapTensors, batch_size: int = 4, tolerance_cells: int = 1) -> dict:
    """How well the auxiliary BEV segmentation head finds the rasterised map lines: a diagnostic of the
    lifted BEV features that stays informative where the vector mAP is near zero (not a MapTR metric).

    ``ap``: average precision of the cell scores (every class) with the line cells positive and the
    cells within ``tolerance_cells`` of a line left out (threshold-free; ``positive_share`` is what
    chance scores);
    ``precision`` / ``recall`` / ``f1`` at logit 0, each side matched within the tolerance."""
    import torch.nn.functional as F

    was_training = model.training
    model.eval()
    tp = fp = fn = 0
    k = 2 * tolerance_cells + 1
    scores, labels = [], []
    try:
        for start in range(0, len(data), batch_size):
            b = data.batch(list(range(start, min(len(data), start + batch_size))))
            logits = model(b["img"], b["lidar2img"], b["img_hw"])["bev_seg"]
            pred = (logits > 0).float()
            tgt = b["bev_target"].float()
            tgt_near = F.max_pool2d(tgt, k, 1, tolerance_cells) > 0
            pred_near = F.max_pool2d(pred, k, 1, tolerance_cells) > 0
            tp += int((pred.bool() & tgt_near).sum())
            fp += int((pred.bool() & ~tgt_near).sum())
            fn += int((tgt.bool() & ~pred_near).sum())
            counted = (tgt > 0) | ~tgt_near
            scores.append(logits[counted])
            labels.append(tgt[counted] > 0)
    finally:
        model.train(was_training)
    y = torch.cat(labels)[torch.cat(scores).argsort(descending=True)].double()
    hits = y.cumsum(0)
    ap = float((hits / torch.arange(1, len(y) + 1, dtype=torch.float64) * y).sum() / y.sum().clamp(min=1))
    precision, recall = tp / max(1, tp + fp), tp / max(1, tp + fn)
    f1 = 2 * precision * recall / (precision + recall) if precision + recall > 0 else 0.0
    return {
        "ap": ap,
        "positive_share": float(y.mean()) if len(y) else 0.0,
        "precision": precision,
        "recall": recall,
        "f1": f1,
    }


def results_json(preds: dict[str, Scored], classes: Sequence[str], meta: dict | None = None) -> dict:
    """MapTR's ``nuscmap_results.json`` layout."""
    label = {c: i for i, c in enumerate(classes)}
    return {
        "meta": {"use_camera": True, "use_lidar": False, **(meta or {})},
        "results": [
            {
                "sample_token": tok,
                "vectors": [
                    {
                        "pts": np.round(p, 4).tolist(),
                        "pts_num": len(p),
                        "cls_name": c,
                        "type": label[c],
                        "confidence_level": round(s, 6),
                    }
                    for c, p, s in vecs
                ],
            }
            for tok, vecs in preds.items()
        ],
    }


def write_results(
    path: str | Path, preds: dict[str, Scored], classes: Sequence[str], meta: dict | None = None
) -> Path:
    atomic_write_json(Path(path), results_json(preds, classes, meta))
    return Path(path)


def score_with_nuav2_eval(
    pred_path: str | Path,
    dataroot: str | Path,
    version: str,
    split: str,
    classes: Sequence[str],
    out_path: str | Path,
    patch: tuple[float, float] = DEFAULT_PATCH,
) -> dict:
    """Run ``nuav2 eval PRED --dataroot D --version V --split S --classes ... --patch F R --out OUT`` in
    this process (its printed table is captured) and return the result it wrote. ``patch``: the
    model's (forward, right) metres, so the GT is cut where the predictions live."""
    from nuav2.cli import main

    argv = [
        "eval",
        str(pred_path),
        "--dataroot",
        str(dataroot),
        "--version",
        version,
        "--split",
        split,
        "--classes",
        *classes,
        "--patch",
        str(patch[0]),
        str(patch[1]),
        "--out",
        str(out_path),
        "--json",
    ]
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        rc = main(argv)
    if rc != 0:
        raise RuntimeError(f"nuav2 {' '.join(argv)} exited with {rc}")
    return json.loads(Path(out_path).read_text())


def score_in_process(preds: dict[str, Scored], gts: dict, classes: Sequence[str]) -> dict:
    """The library call ``nuav2 eval`` makes (MapTR thresholds, 100-point resampling)."""
    from nuav2.evaluate import MAP_THRESHOLDS_M
    from nuav2.evaluate.chamfer_ap import evaluate_vectors

    return evaluate_vectors(
        gts,
        {t: [(c, p, s) for c, p, s in v] for t, v in preds.items()},
        classes=list(classes),
        thresholds=list(MAP_THRESHOLDS_M),
        n_resample=100,
    )
