"""Benchmark: vectorised chamfer AP against the per-sample reference, on synthetic MapTR-like data.

Each synthetic sample is a 30 m x 60 m lidar-frame patch (x right, y forward) with a lightly
curved road: lane dividers, two road boundaries, lane centerlines, a turning centerline and
zebra crossings (closed rings), ~20-30 GT polylines in all. Predictions imitate a decent
MapTRv2 output: 20-point lines, a noisy copy of most GT lines (offset 0.1-1.2 m, high score),
some duplicates (lower score), and random false positives up to ~50 vectors per sample.
"""

from __future__ import annotations

import time

import numpy as np

from nuav2.bench.timing import Stopwatch, machine
from nuav2.evaluate.chamfer_ap import DEFAULT_CLASSES, evaluate_vectors
from nuav2.evaluate.reference_ap import reference_evaluate
from nuav2.evaluate.resample import resample_polylines

PRED_POINTS = 20  # MapTR decodes 20 points per vector


def _road_line(
    rng: np.random.Generator, x0: float, bend: float, y0: float = -30.0, y1: float = 30.0, n: int = 20
) -> np.ndarray:
    y = np.linspace(y0, y1, n)
    return np.stack([x0 + bend * (y / 30.0) ** 2 + rng.normal(0, 0.02, n), y], axis=1)


def _zebra(rng: np.random.Generator, y: float) -> np.ndarray:
    w, h = rng.uniform(10, 16), rng.uniform(3, 5)
    x = rng.uniform(-2, 2)
    return np.array([[x - w / 2, y], [x + w / 2, y], [x + w / 2, y + h], [x - w / 2, y + h], [x - w / 2, y]])


def synthetic_sample(rng: np.random.Generator) -> list[tuple[str, np.ndarray]]:
    """GT vectors of one synthetic sample (lidar frame)."""
    n_lanes = int(rng.integers(4, 7))
    width = 3.5
    bend = rng.uniform(-4, 4)
    xs = (np.arange(n_lanes + 1) - n_lanes / 2) * width
    gts: list[tuple[str, np.ndarray]] = []
    for x in xs[1:-1]:  # dashed dividers come in pieces
        cuts = np.sort(rng.uniform(-25, 25, 2))
        for y0, y1 in ((-30, cuts[0]), (cuts[0] + 2, cuts[1]), (cuts[1] + 2, 30)):
            if y1 - y0 > 1:
                gts.append(("divider", _road_line(rng, x, bend, y0, y1, int(rng.integers(2, 15)))))
    for x in (xs[0] - 0.5, xs[-1] + 0.5):
        gts.append(("boundary", _road_line(rng, x, bend, n=int(rng.integers(10, 40)))))
    for a, b in zip(xs[:-1], xs[1:]):
        gts.append(("centerline", _road_line(rng, (a + b) / 2, bend, n=int(rng.integers(10, 60)))))
    turn = np.linspace(0, np.pi / 2, 25)
    r = rng.uniform(8, 14)
    gts.append(("centerline", np.stack([xs[-1] - width / 2 + r * (1 - np.cos(turn)), r * np.sin(turn)], 1)))
    for _ in range(int(rng.integers(1, 4))):
        gts.append(("ped_crossing", _zebra(rng, rng.uniform(-28, 24))))
    return gts


def synthetic_predictions(
    rng: np.random.Generator, gts: list[tuple[str, np.ndarray]], n_target: int = 50
) -> list[tuple[str, np.ndarray, float]]:
    """Noisy copies, duplicates and false positives, as 20-point lines with scores."""
    preds: list[tuple[str, np.ndarray, float]] = []
    lines = resample_polylines([p for _, p in gts], PRED_POINTS)
    for (cls, _), line in zip(gts, lines):
        if rng.random() < 0.1:
            continue  # missed
        shift = rng.normal(0, 1, 2)
        shift *= rng.uniform(0.1, 1.2) / max(np.linalg.norm(shift), 1e-9)
        noisy = line + shift + rng.normal(0, 0.15, line.shape)
        preds.append((cls, noisy, float(rng.uniform(0.4, 1.0))))
        if rng.random() < 0.15:
            preds.append((cls, noisy + rng.normal(0, 0.3, line.shape), float(rng.uniform(0.1, 0.6))))
    while len(preds) < n_target:
        start = rng.uniform([-15, -30], [15, 30])
        steps = rng.normal(0, 1, (PRED_POINTS, 2)) * 0.3 + rng.normal(0, 1, 2) * 1.5
        cls = DEFAULT_CLASSES[int(rng.integers(0, len(DEFAULT_CLASSES)))]
        preds.append((cls, start + np.cumsum(steps, axis=0), float(rng.uniform(0.0, 0.5))))
    return preds


def synthetic_dataset(n_samples: int, seed: int = 0) -> tuple[dict, dict]:
    """({token: GT vectors}, {token: predictions}) for ``n_samples`` synthetic samples."""
    rng = np.random.default_rng(seed)
    gts, preds = {}, {}
    for i in range(n_samples):
        token = f"{i:032x}"
        gts[token] = synthetic_sample(rng)
        preds[token] = synthetic_predictions(rng, gts[token])
    return gts, preds


def _max_abs_diff(a: dict, b: dict) -> float:
    diffs = [abs(a["ap"][c][t] - b["ap"][c][t]) for c in a["ap"] for t in a["ap"][c]]
    diffs.append(abs(a["mAP"] - b["mAP"]))
    return float(max(diffs))


def run_eval_benchmark(n_samples: int = 6000, seed: int = 0, skip_reference: bool = False) -> dict:
    """Time :func:`evaluate_vectors` and the reference on the same data, one after the other (the
    reference takes minutes: one run each), wall and CPU seconds and the load after each; report the
    speed-up in both."""
    start = machine()
    gts, preds = synthetic_dataset(n_samples, seed)
    n_gt = sum(len(v) for v in gts.values())
    n_pred = sum(len(v) for v in preds.values())

    t0 = time.perf_counter()
    warm_g, warm_p = synthetic_dataset(3, seed + 1)
    evaluate_vectors(warm_g, warm_p)  # numba compiles (or loads its cache) here, not in the timing
    warmup_s = time.perf_counter() - t0

    fast_sw = Stopwatch()
    with fast_sw:
        fast = evaluate_vectors(gts, preds)
    out = {
        "n_samples": n_samples,
        "n_gt_vectors": n_gt,
        "n_pred_vectors": n_pred,
        "eval_s": round(fast_sw.wall_s[0], 4),
        "eval_cpu_s": round(fast_sw.cpu_s[0], 4),  # all threads of this process (numba's too)
        "warmup_s": round(warmup_s, 3),
        "mAP": fast["mAP"],
        "stats": fast["stats"],
        "machine_at_start": start,
    }
    if not skip_reference:
        ref_sw = Stopwatch()
        with ref_sw:
            ref = reference_evaluate(gts, preds, progress=True)
        out.update(
            {
                "reference_s": round(ref_sw.wall_s[0], 3),
                "reference_cpu_s": round(ref_sw.cpu_s[0], 3),
                "speedup": round(ref_sw.wall_s[0] / fast_sw.wall_s[0], 2),
                "speedup_cpu": round(ref_sw.cpu_s[0] / max(fast_sw.cpu_s[0], 1e-9), 2),
                "max_ap_abs_diff": _max_abs_diff(fast, ref),
            }
        )
    loads = fast_sw.load + (ref_sw.load if not skip_reference else [])
    out["load_1min_after_each"] = [round(x, 2) for x in loads]
    return out
