"""Chamfer-distance AP for vectorised map predictions (MapTR protocol), vectorised end to end.

Protocol (MapTR ``map_utils/{mean_ap,tpfp,tpfp_chamfer}.py``; see docs/evaluation.md):

* GT lines are resampled to ``n_resample`` points by arc length; so is every prediction,
  except one that already has exactly ``n_resample`` vertices (MapTR keeps it as is).
  Predictions with fewer than 2 points are dropped.
* A (prediction, GT) pair of one sample and class is a *candidate* only where the two lines,
  each buffered by 2.0 m with flat caps and mitre joins, intersect; other pairs score -100.
* score = -CD, CD = 1/2 (mean over prediction points of the nearest-GT-point distance + mean
  over GT points of the nearest-prediction-point distance).
* Per sample, predictions in descending score take their argmax GT over all GTs (first GT
  on ties); TP if CD <= thr and that GT is uncovered, else FP. No GT -> all FP.
* Per class, all samples' predictions are ranked by score; AP is the VOC all-point area
  under the precision envelope. Headline mAP = per-class mean over thresholds, then the mean
  over all classes (a class without GT scores 0).

Ties in score are broken deterministically so that the order of samples or vectors in the
input never changes the result: descending score, then sample token, then the raw input
coordinates' float64 bytes (equal bytes means identical vectors, whose order is immaterial).

How it is fast (no Python loop over pairs): one numba kernel computes a cheap bounding-box
lower bound on CD and the exact CD with early exit for every same-sample pair, discarding
pairs that cannot pass the largest threshold (they can never be TP nor change a TP). Only the
few remaining pairs need the candidate test; a margin-safe geometric test proves most buffer
intersections in numba, and the rest go to GEOS (shapely 2 vectorised buffer + intersects),
exactly as MapTR computes them. Greedy matching is one more numba kernel.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numba
import numpy as np
import shapely

from nuav2.evaluate import MAP_CLASSES, MAP_THRESHOLDS_M
from nuav2.evaluate.resample import bboxes, pack_polylines, resample_packed

log = logging.getLogger(__name__)

DEFAULT_CLASSES = MAP_CLASSES
DEFAULT_THRESHOLDS = MAP_THRESHOLDS_M
BUFFER_M = 2.0  # MapTR's linewidth for the candidate test
BUFFER_QUAD_SEGS = 16  # shapely 1.8's default resolution, which MapTR ran with
NONCANDIDATE_SCORE = -100.0
# Margins of the numba "buffers surely intersect" test: 10x GEOS's buffer input simplification
# tolerance (1 % of the buffer distance), so the test never claims an intersection GEOS denies.
_SURE_MARGIN_M = 0.2
_PRUNE_EPS = 1e-9

GtVectors = Mapping[str, Sequence[tuple[str, np.ndarray]]]
PredVectors = Mapping[str, Sequence[tuple[str, np.ndarray, float]]]


@dataclass
class _Lines:
    """All lines of one kind (GT or prediction), flattened over samples, in input order."""

    cls: np.ndarray  # (n,) int class index
    sample: np.ndarray  # (n,) int index into the sorted sample tokens
    pts: np.ndarray  # (n, n_resample, 2) float64 resampled points
    score: np.ndarray  # (n,) float64 (GT: zeros)
    raw: list[np.ndarray]  # input coordinates, for tie-breaking


def _as_points(pts, where: str) -> np.ndarray:
    arr = np.asarray(pts, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise ValueError(f"{where}: points must have shape (N, 2), got {arr.shape}")
    return arr if arr.flags.c_contiguous else np.ascontiguousarray(arr)


def _collect(
    vectors: Mapping, tok_index: dict[str, int], class_index: dict[str, int], n_resample: int, is_pred: bool
) -> tuple[_Lines, int]:
    """Flatten, validate and resample; returns the lines and how many were dropped (< 2 points)."""
    cls, sample, score, raw, where = [], [], [], [], []
    dropped = 0
    kind = "prediction" if is_pred else "GT"
    for token, vecs in vectors.items():
        s = tok_index[token]
        for i, vec in enumerate(vecs):
            name = vec[0]
            if name not in class_index:
                continue
            pts = _as_points(vec[1], f"sample {token}: {kind} vector {i} ({name})")
            if len(pts) < 2:
                dropped += 1
                continue
            where.append((token, i, name))  # one entry per kept line, as ``raw``
            if is_pred:
                conf = float(vec[2])
                if not np.isfinite(conf):
                    raise ValueError(f"sample {token}: prediction {i} ({name}) has non-finite score {vec[2]}")
                score.append(conf)
            cls.append(class_index[name])
            sample.append(s)
            raw.append(pts)
    coords, offsets = pack_polylines(raw)
    finite = np.isfinite(coords).all(axis=1)
    if not finite.all():
        token, i, name = where[int(np.searchsorted(offsets, np.argmin(finite), side="right")) - 1]
        raise ValueError(f"sample {token}: {kind} vector {i} ({name}) has NaN or Inf points")
    resampled = resample_packed(coords, offsets, n_resample)
    if is_pred:  # MapTR keeps a prediction that already has exactly n_resample points
        for k in np.flatnonzero(np.diff(offsets) == n_resample):
            resampled[k] = raw[k]
    lines = _Lines(
        cls=np.asarray(cls, dtype=np.int64),
        sample=np.asarray(sample, dtype=np.int64),
        pts=resampled,
        score=np.asarray(score if is_pred else np.zeros(len(cls)), dtype=np.float64),
        raw=raw,
    )
    return lines, dropped


@numba.njit(cache=True, inline="always")
def _point_bbox_dist(x: float, y: float, bb: np.ndarray) -> float:
    dx = max(bb[0] - x, 0.0, x - bb[2])
    dy = max(bb[1] - y, 0.0, y - bb[3])
    return np.sqrt(dx * dx + dy * dy)


@numba.njit(cache=True, parallel=True, fastmath={"nnan", "nsz"})
def _pair_chamfer_kernel(
    pred_pts, pred_bb, pred_sample, pair_start, gt_pts, gt_bb, gt_first, gt_count, cd_max, out_cd
):
    """CD of every same-sample (pred, GT) pair; +inf where it provably exceeds ``cd_max``."""
    n = pred_pts.shape[1]
    m = gt_pts.shape[1]
    for p in numba.prange(pred_pts.shape[0]):
        s = pred_sample[p]
        colmin = np.empty(m)
        for k in range(gt_count[s]):
            g = gt_first[s] + k
            # CD >= the gap between the two bounding boxes (every point is at least that far).
            gap_x = max(gt_bb[g, 0] - pred_bb[p, 2], 0.0, pred_bb[p, 0] - gt_bb[g, 2])
            gap_y = max(gt_bb[g, 1] - pred_bb[p, 3], 0.0, pred_bb[p, 1] - gt_bb[g, 3])
            if gap_x * gap_x + gap_y * gap_y > cd_max * cd_max:
                out_cd[pair_start[p] + k] = np.inf
                continue
            # Tighter lower bound: each point is at least as far from the other line as from its bbox.
            lb_a = 0.0
            for i in range(n):
                lb_a += _point_bbox_dist(pred_pts[p, i, 0], pred_pts[p, i, 1], gt_bb[g])
            lb_b = 0.0
            for j in range(m):
                lb_b += _point_bbox_dist(gt_pts[g, j, 0], gt_pts[g, j, 1], pred_bb[p])
            if 0.5 * (lb_a / n + lb_b / m) > cd_max:
                out_cd[pair_start[p] + k] = np.inf
                continue
            for j in range(m):
                colmin[j] = np.inf
            sum_a = 0.0
            pruned = False
            for i in range(n):
                px = pred_pts[p, i, 0]
                py = pred_pts[p, i, 1]
                rowmin = np.inf
                for j in range(m):
                    dx = px - gt_pts[g, j, 0]
                    dy = py - gt_pts[g, j, 1]
                    d2 = dx * dx + dy * dy
                    rowmin = min(rowmin, d2)
                    colmin[j] = min(colmin[j], d2)
                sum_a += np.sqrt(rowmin)
                if 0.5 * sum_a / n > cd_max:  # the remaining terms are >= 0
                    pruned = True
                    break
            if pruned:
                out_cd[pair_start[p] + k] = np.inf
                continue
            sum_b = 0.0
            for j in range(m):
                sum_b += np.sqrt(colmin[j])
            cd = 0.5 * (sum_a / n + sum_b / m)
            out_cd[pair_start[p] + k] = cd if cd <= cd_max else np.inf


@numba.njit(cache=True, inline="always")
def _point_polyline_dist(x: float, y: float, line: np.ndarray) -> float:
    best = np.inf
    for j in range(line.shape[0] - 1):
        ax = line[j, 0]
        ay = line[j, 1]
        abx = line[j + 1, 0] - ax
        aby = line[j + 1, 1] - ay
        l2 = abx * abx + aby * aby
        t = 0.0
        if l2 > 0.0:
            t = min(max(((x - ax) * abx + (y - ay) * aby) / l2, 0.0), 1.0)
        dx = x - (ax + t * abx)
        dy = y - (ay + t * aby)
        best = min(best, dx * dx + dy * dy)
    return np.sqrt(best)


@numba.njit(cache=True)
def _vertex_in_both_buffers(a: np.ndarray, b: np.ndarray, width: float, margin: float) -> bool:
    """Some vertex of ``a`` lies, with ``margin``, inside both flat-cap buffers (of a and of b).

    A vertex of ``a`` farther than ``margin`` from a's endpoints is inside a's buffer: its
    nearest point on (the GEOS-simplified) a is no endpoint. It is inside b's buffer when its
    distance to b is <= width - margin and both endpoints of b are farther than that distance
    + margin, so b's nearest point is no endpoint either and no flat cap can cut it off. Joins
    (mitre or limited mitre) only add area, so the test is conservative.
    """
    n = a.shape[0]
    for r in range(n):
        i = (n // 2 + (r + 1) // 2 * (1 if r % 2 else -1)) % n  # middle vertices first
        x = a[i, 0]
        y = a[i, 1]
        if (
            np.hypot(x - a[0, 0], y - a[0, 1]) <= margin
            or np.hypot(x - a[n - 1, 0], y - a[n - 1, 1]) <= margin
        ):
            continue
        d = _point_polyline_dist(x, y, b)
        if d > width - margin:
            continue
        m = b.shape[0]
        if (
            np.hypot(x - b[0, 0], y - b[0, 1]) > d + margin
            and np.hypot(x - b[m - 1, 0], y - b[m - 1, 1]) > d + margin
        ):
            return True
    return False


@numba.njit(cache=True, parallel=True)
def _sure_candidate_kernel(pred_pts, gt_pts, pair_p, pair_g, width, margin, out):
    for k in numba.prange(pair_p.shape[0]):
        a = pred_pts[pair_p[k]]
        b = gt_pts[pair_g[k]]
        out[k] = _vertex_in_both_buffers(a, b, width, margin) or _vertex_in_both_buffers(b, a, width, margin)


@numba.njit(cache=True)
def _greedy_kernel(order, best_gt, best_cd, thresholds, n_gt):
    """MapTR's greedy assignment; a prediction's argmax GT is fixed, coverage is per threshold."""
    n_thr = thresholds.shape[0]
    covered = np.zeros((n_thr, max(n_gt, 1)), dtype=np.bool_)
    tp = np.zeros((n_thr, order.shape[0]), dtype=np.float64)
    for r in range(order.shape[0]):
        p = order[r]
        g = best_gt[p]
        if g < 0:
            continue
        for t in range(n_thr):
            if best_cd[p] <= thresholds[t] and not covered[t, g]:
                covered[t, g] = True
                tp[t, r] = 1.0
    return tp


def score_order(scores: np.ndarray, sample: np.ndarray, raw: list[np.ndarray]) -> np.ndarray:
    """Ranking of predictions: descending score, then sample index, then raw coordinate bytes."""
    order = np.lexsort((sample, -scores))
    s, t = scores[order], sample[order]
    tied = np.flatnonzero((s[1:] == s[:-1]) & (t[1:] == t[:-1]))
    if len(tied):
        # Runs of equal (score, sample): re-sort each run by the raw bytes (rare, so a Python sort).
        starts = tied[np.r_[True, np.diff(tied) > 1]]
        ends = tied[np.r_[np.diff(tied) > 1, True]] + 2
        for a, b in zip(starts, ends):
            run = order[a:b]
            order[a:b] = sorted(run, key=lambda k: raw[k].tobytes())
    return order


def voc_area_ap(tp: np.ndarray, fp: np.ndarray, num_gts: int) -> float:
    """VOC all-point AP from ranked TP/FP flags: area under the monotone precision envelope."""
    tp_cum = np.cumsum(tp)
    fp_cum = np.cumsum(fp)
    eps = np.finfo(np.float32).eps
    recall = tp_cum / max(num_gts, eps)
    precision = tp_cum / np.maximum(tp_cum + fp_cum, eps)
    mrec = np.concatenate([[0.0], recall, [1.0]])
    mpre = np.concatenate([[0.0], precision, [0.0]])
    mpre = np.maximum.accumulate(mpre[::-1])[::-1]
    steps = np.flatnonzero(mrec[1:] != mrec[:-1])
    return float(np.sum((mrec[steps + 1] - mrec[steps]) * mpre[steps + 1]))


def _geos_candidates(
    pred_pts: np.ndarray, gt_pts: np.ndarray, pair_p: np.ndarray, pair_g: np.ndarray
) -> np.ndarray:
    """MapTR's exact test: do the 2 m flat-cap mitre buffers of the two lines intersect?"""
    up, inv_p = np.unique(pair_p, return_inverse=True)
    ug, inv_g = np.unique(pair_g, return_inverse=True)
    buf_p = candidate_buffers(shapely.linestrings(pred_pts[up]))
    buf_g = candidate_buffers(shapely.linestrings(gt_pts[ug]))
    return shapely.intersects(buf_p[inv_p], buf_g[inv_g])


def candidate_buffers(lines: np.ndarray) -> np.ndarray:
    """2 m flat-cap mitre buffers of an array of LineStrings (MapTR's candidate geometry).

    GEOS refuses some degenerate lines (e.g. a 1e-19 m long one: "orientationIndex encountered
    NaN/Inf"); such a line gets an empty buffer, i.e. is never a candidate, instead of crashing.
    """
    kw = dict(quad_segs=BUFFER_QUAD_SEGS, cap_style="flat", join_style="mitre")
    try:
        with np.errstate(invalid="ignore"):
            return shapely.buffer(lines, BUFFER_M, **kw)
    except shapely.errors.GEOSException:
        out = np.empty(len(lines), dtype=object)
        for i, line in enumerate(lines):
            try:
                out[i] = shapely.buffer(line, BUFFER_M, **kw)
            except shapely.errors.GEOSException as e:
                log.warning("no candidate buffer for a degenerate line (%s): %s", e, line.wkt[:80])
                out[i] = shapely.Polygon()
        return out


def _match_class(
    pred: _Lines, gt: _Lines, c: int, thresholds: np.ndarray, n_samples: int, stats: dict
) -> tuple[np.ndarray, int, int]:
    """TP flags (n_thr, n_pred_c) in rank order, number of GTs and of predictions of class ``c``."""
    p_idx = np.flatnonzero(pred.cls == c)
    g_idx = np.flatnonzero(gt.cls == c)
    g_idx = g_idx[np.argsort(gt.sample[g_idx], kind="stable")]  # by sample, input order within
    p_pts = np.ascontiguousarray(pred.pts[p_idx])
    g_pts = np.ascontiguousarray(gt.pts[g_idx])
    p_sample = pred.sample[p_idx]
    gt_count = np.bincount(gt.sample[g_idx], minlength=n_samples).astype(np.int64)
    gt_first = np.concatenate([[0], np.cumsum(gt_count)[:-1]]).astype(np.int64)
    n_pairs_per_pred = gt_count[p_sample]
    pair_start = np.concatenate([[0], np.cumsum(n_pairs_per_pred)]).astype(np.int64)
    cd_max = float(thresholds.max()) * (1.0 + _PRUNE_EPS) + _PRUNE_EPS

    cd = np.empty(pair_start[-1], dtype=np.float64)
    if len(cd):
        _pair_chamfer_kernel(
            p_pts, bboxes(p_pts), p_sample, pair_start, g_pts, bboxes(g_pts), gt_first, gt_count, cd_max, cd
        )
    close = np.flatnonzero(np.isfinite(cd))
    pair_p = np.repeat(np.arange(len(p_idx)), n_pairs_per_pred)[close]
    pair_k = close - pair_start[pair_p]  # GT position within its sample's class list
    pair_g = gt_first[p_sample[pair_p]] + pair_k

    sure = np.zeros(len(close), dtype=np.bool_)
    if len(close):
        _sure_candidate_kernel(p_pts, g_pts, pair_p, pair_g, BUFFER_M, _SURE_MARGIN_M, sure)
    unsure = np.flatnonzero(~sure)
    candidate = sure.copy()
    if len(unsure):
        candidate[unsure] = _geos_candidates(p_pts, g_pts, pair_p[unsure], pair_g[unsure])
    stats["pairs"] += int(len(cd))
    stats["close_pairs"] += int(len(close))
    stats["geos_checked_pairs"] += int(len(unsure))

    # argmax over GTs of -CD among candidates; ties -> first GT in the sample's list.
    best_gt = np.full(len(p_idx), -1, dtype=np.int64)
    best_cd = np.full(len(p_idx), np.inf)
    keep = np.flatnonzero(candidate)
    if len(keep):
        kp, kk, kg, kc = pair_p[keep], pair_k[keep], pair_g[keep], cd[close][keep]
        o = np.lexsort((kk, kc, kp))
        first = o[np.r_[True, kp[o][1:] != kp[o][:-1]]]
        best_gt[kp[first]] = kg[first]
        best_cd[kp[first]] = kc[first]

    order = score_order(pred.score[p_idx], p_sample, [pred.raw[k] for k in p_idx])
    tp = _greedy_kernel(order, best_gt, best_cd, thresholds, len(g_idx))
    return tp, len(g_idx), len(p_idx)


def _thr_key(thr: float) -> str:
    return str(float(thr))


def evaluate_vectors(
    gts: GtVectors,
    preds: PredVectors,
    classes: Sequence[str] = DEFAULT_CLASSES,
    thresholds: Sequence[float] = DEFAULT_THRESHOLDS,
    n_resample: int = 100,
) -> dict:
    """Chamfer AP per class and threshold, and mAP, of ``preds`` against ``gts`` (MapTR protocol).

    ``gts``: {sample_token: [(cls_name, (N, 2) points)]} in the evaluation frame (MapTR: lidar);
    it defines the evaluated samples. ``preds``: {sample_token: [(cls_name, (N, 2) points,
    score)]}; a token missing from ``preds`` has no predictions, a token absent from ``gts`` is
    an error. Vectors of classes outside ``classes`` are ignored. Returns a JSON-ready dict:
    ``ap[cls][thr]``, ``map_per_threshold[thr]`` (classes with GT only), ``class_mean_ap[cls]``,
    ``mAP`` (mean over all classes of the per-class mean over thresholds), counts and stats.
    """
    thr = np.asarray([float(t) for t in thresholds], dtype=np.float64)
    if len(thr) == 0 or np.any(~np.isfinite(thr)) or np.any(thr <= 0) or np.any(thr >= -NONCANDIDATE_SCORE):
        raise ValueError(f"thresholds must be in (0, {-NONCANDIDATE_SCORE}) m, got {list(thresholds)}")
    if len(np.unique(thr)) != len(thr):  # a repeat would count twice in mAP but once in the table
        raise ValueError(f"thresholds must be distinct, got {list(thresholds)}")
    if len(set(classes)) != len(classes) or not classes:
        raise ValueError(f"classes must be distinct and non-empty, got {list(classes)}")
    tokens = sorted(gts)
    tok_index = {t: i for i, t in enumerate(tokens)}
    unknown = [t for t in preds if t not in tok_index]
    if unknown:
        raise ValueError(
            f"{len(unknown)} predicted sample tokens are not in the GT set "
            f"(wrong split or version?), e.g. {unknown[:3]}"
        )
    class_index = {name: i for i, name in enumerate(classes)}
    gt, gt_dropped = _collect(gts, tok_index, class_index, n_resample, is_pred=False)
    pred, pred_dropped = _collect(preds, tok_index, class_index, n_resample, is_pred=True)
    if gt_dropped:
        log.warning("%d GT vectors with fewer than 2 points were ignored", gt_dropped)

    stats = {"pairs": 0, "close_pairs": 0, "geos_checked_pairs": 0}
    ap = np.zeros((len(classes), len(thr)))
    num_gts, num_preds = {}, {}
    for c, name in enumerate(classes):
        tp, n_gt, n_pred = _match_class(pred, gt, c, thr, len(tokens), stats)
        num_gts[name], num_preds[name] = n_gt, n_pred
        for t in range(len(thr)):
            ap[c, t] = voc_area_ap(tp[t], 1.0 - tp[t], n_gt)
    return summarize(
        ap,
        classes,
        thr,
        num_gts,
        num_preds,
        extra={
            "n_samples": len(tokens),
            "n_samples_without_predictions": sum(1 for t in tokens if not preds.get(t)),
            "n_predictions_dropped": pred_dropped,
            "n_gts_dropped": gt_dropped,
            "stats": stats,
        },
    )


def summarize(
    ap: np.ndarray,
    classes: Sequence[str],
    thresholds: Iterable[float],
    num_gts: dict[str, int],
    num_preds: dict[str, int],
    extra: dict | None = None,
) -> dict:
    """The result dict from an AP table (n_classes, n_thresholds), MapTR's two mAP conventions."""
    thr_keys = [_thr_key(t) for t in thresholds]
    has_gt = np.array([num_gts[c] > 0 for c in classes])
    map_per_thr = {k: float(ap[has_gt, t].mean()) if has_gt.any() else 0.0 for t, k in enumerate(thr_keys)}
    class_mean = ap.mean(axis=1)
    out = {
        "classes": list(classes),
        "thresholds": [float(t) for t in thresholds],
        "ap": {c: {k: float(ap[i, t]) for t, k in enumerate(thr_keys)} for i, c in enumerate(classes)},
        "map_per_threshold": map_per_thr,
        "class_mean_ap": {c: float(class_mean[i]) for i, c in enumerate(classes)},
        "mAP": float(class_mean.mean()),
        "num_gts": dict(num_gts),
        "num_preds": dict(num_preds),
    }
    out.update(extra or {})
    return out


def predicted_classes(
    preds: PredVectors, known: Sequence[str] = DEFAULT_CLASSES
) -> tuple[list[str], list[str], list[str]]:
    """Which classes a result file predicts: (known classes with predictions, in ``known`` order;
    known classes without a single prediction; predicted classes outside ``known``).

    A 3-class model (MapTRv2 without centerlines) has no centerline predictions: averaging that
    class in as AP 0 would score it 25 % too low, so callers evaluate the first list.
    """
    seen = {vec[0] for vecs in preds.values() for vec in vecs}
    return ([c for c in known if c in seen], [c for c in known if c not in seen],
            sorted(str(c) for c in seen - set(known)))
