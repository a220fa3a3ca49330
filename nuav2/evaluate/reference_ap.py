"""Straightforward chamfer AP, written the way MapTR's evaluator is: per sample, per pair, in Python.

It is the oracle for :mod:`nuav2.evaluate.chamfer_ap` in tests and the baseline in
``nuav2 bench eval``. It shares no code with the vectorised evaluator: shapely's
``line_interpolate_point`` resamples, an STRtree of 2 m flat-cap mitre buffers proposes
candidate pairs that an exact ``intersects`` confirms, scipy's ``cdist`` gives every candidate's
chamfer distance, and a Python loop does the greedy matching. It uses the same tie-breaking
(descending score, sample token, raw coordinate bytes) so that results agree exactly.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import shapely
from scipy.spatial import distance

from nuav2.evaluate.chamfer_ap import (
    BUFFER_M,
    BUFFER_QUAD_SEGS,
    DEFAULT_CLASSES,
    DEFAULT_THRESHOLDS,
    NONCANDIDATE_SCORE,
    GtVectors,
    PredVectors,
    summarize,
)
from nuav2.progress import progress_bar


def _resample(pts: np.ndarray, n: int) -> np.ndarray:
    line = shapely.LineString(pts)
    return shapely.get_coordinates(shapely.line_interpolate_point(line, np.linspace(0, line.length, n)))


def _buffer(pts: np.ndarray) -> shapely.Polygon:
    """MapTR's 2 m flat-cap mitre buffer; empty where GEOS refuses a degenerate line."""
    try:
        return shapely.LineString(pts).buffer(
            BUFFER_M, quad_segs=BUFFER_QUAD_SEGS, cap_style="flat", join_style="mitre"
        )
    except shapely.errors.GEOSException:
        return shapely.Polygon()


def _score_matrix(pred_lines: list[np.ndarray], gt_lines: list[np.ndarray]) -> np.ndarray:
    """MapTR's ``custom_polyline_score``: -CD for candidate pairs, -100 elsewhere."""
    pred_buf = [_buffer(p) for p in pred_lines]
    gt_buf = [_buffer(g) for g in gt_lines]
    tree = shapely.STRtree(pred_buf)
    scores = np.full((len(pred_lines), len(gt_lines)), NONCANDIDATE_SCORE)
    for j, gbuf in enumerate(gt_buf):
        for i in tree.query(gbuf):
            if pred_buf[i].intersects(gbuf):
                dist = distance.cdist(pred_lines[i], gt_lines[j], "euclidean")
                scores[i, j] = -(dist.min(axis=1).mean() + dist.min(axis=0).mean()) / 2
    return scores


def _tpfp(
    preds: list[tuple[np.ndarray, float, bytes]], gt_lines: list[np.ndarray], thresholds: Sequence[float]
) -> list[list[int]]:
    """Per threshold, TP flags of this sample's predictions (given in rank order)."""
    tp = [[0] * len(preds) for _ in thresholds]
    if not gt_lines or not preds:
        return tp
    scores = _score_matrix([p[0] for p in preds], gt_lines)
    best = scores.max(axis=1)
    argbest = scores.argmax(axis=1)
    for t, thr in enumerate(thresholds):
        covered = [False] * len(gt_lines)
        for i in range(len(preds)):
            if best[i] >= -thr and not covered[argbest[i]]:
                covered[argbest[i]] = True
                tp[t][i] = 1
    return tp


def _voc_ap(flags: list[int], num_gts: int) -> float:
    eps = float(np.finfo(np.float32).eps)
    tp_cum = fp_cum = 0
    recall, precision = [], []
    for f in flags:
        tp_cum += f
        fp_cum += 1 - f
        recall.append(tp_cum / max(num_gts, eps))
        precision.append(tp_cum / max(tp_cum + fp_cum, eps))
    mrec = [0.0] + recall + [1.0]
    mpre = [0.0] + precision + [0.0]
    for i in range(len(mpre) - 1, 0, -1):
        mpre[i - 1] = max(mpre[i - 1], mpre[i])
    return sum((mrec[i + 1] - mrec[i]) * mpre[i + 1] for i in range(len(mrec) - 1) if mrec[i + 1] != mrec[i])


def reference_evaluate(
    gts: GtVectors,
    preds: PredVectors,
    classes: Sequence[str] = DEFAULT_CLASSES,
    thresholds: Sequence[float] = DEFAULT_THRESHOLDS,
    n_resample: int = 100,
    progress: bool = False,
) -> dict:
    """Same contract and result as :func:`nuav2.evaluate.chamfer_ap.evaluate_vectors`."""
    unknown = [t for t in preds if t not in gts]
    if unknown:
        raise ValueError(f"{len(unknown)} predicted sample tokens are not in the GT set, e.g. {unknown[:3]}")
    ap = np.zeros((len(classes), len(thresholds)))
    num_gts, num_preds = {}, {}
    for c, name in enumerate(classes):
        ranked: list[tuple[float, str, bytes, int]] = []  # (-score, token, raw bytes, TP flags key)
        flags: list[list[int]] = []
        n_gt = 0
        for token in progress_bar(sorted(gts), desc=f"reference AP {name}", unit="sample",
                                  disable=not progress):
            gt_lines = [
                _resample(np.asarray(p, dtype=np.float64), n_resample)
                for cls, p in gts[token]
                if cls == name and len(p) >= 2
            ]
            n_gt += len(gt_lines)
            sample_preds = []
            for vec in preds.get(token, []):
                cls, p, score = vec[0], np.asarray(vec[1], dtype=np.float64), float(vec[2])
                if cls != name or len(p) < 2:
                    continue
                pts = p if len(p) == n_resample else _resample(p, n_resample)
                sample_preds.append((pts, score, p.tobytes()))
            sample_preds.sort(key=lambda x: (-x[1], x[2]))
            sample_tp = _tpfp(sample_preds, gt_lines, thresholds)
            for i, (_, score, raw) in enumerate(sample_preds):
                ranked.append((-score, token, raw, len(flags)))
                flags.append([sample_tp[t][i] for t in range(len(thresholds))])
        ranked.sort(key=lambda x: x[:3])
        num_gts[name], num_preds[name] = n_gt, len(flags)
        for t in range(len(thresholds)):
            ap[c, t] = _voc_ap([flags[r[3]][t] for r in ranked], n_gt)
    return summarize(ap, classes, thresholds, num_gts, num_preds, extra={"n_samples": len(gts)})
