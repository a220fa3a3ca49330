"""Chamfer AP (MapTR protocol): hand-computed cases, the reference oracle, resampling, file I/O."""

from __future__ import annotations

import json
import random

import numpy as np
import pytest
import shapely
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from nuav2.bench.eval import synthetic_dataset
from nuav2.evaluate.chamfer_ap import (
    _SURE_MARGIN_M,
    BUFFER_M,
    _sure_candidate_kernel,
    evaluate_vectors,
    voc_area_ap,
)
from nuav2.evaluate.reference_ap import reference_evaluate
from nuav2.evaluate.resample import resample_polylines
from nuav2.evaluate.vector_files import load_gt_file, load_predictions

CLASSES = ("divider", "ped_crossing", "boundary", "centerline")


def vline(x: float, y0: float = -20.0, y1: float = 20.0, n: int = 5) -> np.ndarray:
    """A straight line along y at lateral position x."""
    return np.stack([np.full(n, x), np.linspace(y0, y1, n)], axis=1)


def ap_of(result: dict, cls: str = "divider") -> list[float]:
    return [result["ap"][cls][k] for k in ("0.5", "1.0", "1.5")]


def all_aps(result: dict) -> np.ndarray:
    return np.array([[result["ap"][c][k] for k in result["ap"][c]] for c in result["ap"]])


# --- hand-computed cases ---------------------------------------------------------------------


def test_perfect_predictions_score_one():
    gts = {
        "s0": [(c, vline(10.0 * i)) for i, c in enumerate(CLASSES)],
        "s1": [
            ("divider", vline(0.0)),
            ("ped_crossing", np.array([[0, 0], [4, 0], [4, 3], [0, 3], [0, 0.0]])),
        ],
    }
    preds = {t: [(c, p, 0.9) for c, p in v] for t, v in gts.items()}
    r = evaluate_vectors(gts, preds)
    assert r["mAP"] == pytest.approx(1.0, abs=1e-12)
    assert all(v == pytest.approx(1.0, abs=1e-12) for v in r["map_per_threshold"].values())
    assert r["num_gts"] == {"divider": 2, "ped_crossing": 2, "boundary": 1, "centerline": 1}


def test_known_shift_passes_only_looser_thresholds():
    """A 0.7 m lateral shift of a straight line has CD 0.7: FP at 0.5, TP at 1.0 and 1.5."""
    gts = {"s": [("divider", vline(0.0)), ("divider", vline(10.0))]}
    exact_first = {"s": [("divider", vline(0.0), 0.9), ("divider", vline(10.7), 0.8)]}
    r = evaluate_vectors(gts, exact_first)
    assert ap_of(r) == pytest.approx([0.5, 1.0, 1.0], abs=1e-12)  # ranks TP,FP at 0.5 -> 1/2 * 1
    shifted_first = {"s": [("divider", vline(0.0), 0.8), ("divider", vline(10.7), 0.9)]}
    r = evaluate_vectors(gts, shifted_first)
    assert ap_of(r) == pytest.approx([0.25, 1.0, 1.0], abs=1e-12)  # ranks FP,TP -> 1/2 * 1/2
    assert r["class_mean_ap"]["divider"] == pytest.approx(0.75)
    assert r["mAP"] == pytest.approx(0.75 / 4)  # the three classes without GT score 0


def test_missing_predictions_cap_recall():
    gts = {"s": [("boundary", vline(10.0 * i)) for i in range(4)]}
    preds = {"s": [("boundary", vline(0.0), 0.9), ("boundary", vline(20.0), 0.5)]}
    assert ap_of(evaluate_vectors(gts, preds), "boundary") == pytest.approx([0.5] * 3, abs=1e-12)


def test_duplicate_prediction_is_false_positive():
    gts = {"a": [("divider", vline(0.0))], "b": [("divider", vline(0.0))]}
    preds = {
        "a": [("divider", vline(0.0), 0.9), ("divider", vline(0.0), 0.8)],
        "b": [("divider", vline(0.0), 0.7)],
    }
    # ranks TP, FP, TP over 2 GTs: area = 1/2 * 1 + 1/2 * 2/3
    assert ap_of(evaluate_vectors(gts, preds)) == pytest.approx([5 / 6] * 3, abs=1e-12)


def test_argmax_gt_taken_means_fp_even_if_another_gt_passes():
    """MapTR greedy: the prediction's best GT is covered -> FP, although GT 2 is within 1.0 m."""
    gts = {"s": [("divider", vline(0.0)), ("divider", vline(1.0))]}
    preds = {"s": [("divider", vline(0.0), 0.9), ("divider", vline(0.3), 0.8)]}
    r = evaluate_vectors(gts, preds)
    assert ap_of(r) == pytest.approx([0.5, 0.5, 0.5], abs=1e-12)
    assert ap_of(reference_evaluate(gts, preds)) == pytest.approx(ap_of(r), abs=1e-12)


def test_sample_without_gt_makes_predictions_false_positives():
    gts = {"a": [("divider", vline(0.0))], "b": []}
    preds = {"a": [("divider", vline(0.0), 0.5)], "b": [("divider", vline(0.0), 0.9)]}
    # ranks FP (sample b), TP: area = 1 * 1/2
    assert ap_of(evaluate_vectors(gts, preds)) == pytest.approx([0.5] * 3, abs=1e-12)


def test_class_without_gt_counts_zero_in_headline_only():
    gts = {"s": [("divider", vline(0.0))]}
    preds = {"s": [("divider", vline(0.0), 0.9), ("boundary", vline(5.0), 0.9)]}
    r = evaluate_vectors(gts, preds)
    assert r["map_per_threshold"] == pytest.approx({"0.5": 1.0, "1.0": 1.0, "1.5": 1.0})
    assert r["mAP"] == pytest.approx(0.25)
    assert r["class_mean_ap"]["boundary"] == 0.0


def test_non_candidate_pairs_never_match():
    """Collinear lines 0.05 m apart end to end: CD < 0.5 m but flat-cap buffers are disjoint."""
    gt = np.array([[0.0, 0.0], [0.02, 0.0]])
    pred = np.array([[0.07, 0.0], [0.09, 0.0]])
    gts, preds = {"s": [("divider", gt)]}, {"s": [("divider", pred, 0.9)]}
    assert ap_of(evaluate_vectors(gts, preds)) == [0.0, 0.0, 0.0]
    assert ap_of(reference_evaluate(gts, preds)) == [0.0, 0.0, 0.0]
    touching = {"s": [("divider", np.array([[0.01, 0.0], [0.03, 0.0]]), 0.9)]}
    assert ap_of(evaluate_vectors(gts, touching)) == [1.0, 1.0, 1.0]


def test_zero_length_prediction_never_matches():
    """A prediction whose points coincide has an empty buffer, so it is no candidate even at CD ~ 0."""
    gts = {"s": [("divider", np.array([[0.0, 0.0], [0.001, 0.0]]))]}
    preds = {"s": [("divider", np.array([[0.0005, 0.0], [0.0005, 0.0]]), 0.9)]}
    assert ap_of(evaluate_vectors(gts, preds)) == [0.0, 0.0, 0.0]
    assert ap_of(reference_evaluate(gts, preds)) == [0.0, 0.0, 0.0]


def test_degenerate_tiny_lines_do_not_crash():
    """GEOS cannot buffer a 1e-19 m line; it becomes a non-candidate in both implementations."""
    tiny = np.array([[2.6e-20, -2.7e-20], [1.3e-19, 2.2e-20], [-1.1e-19, 7.5e-20]])
    gts = {"s": [("divider", tiny), ("divider", vline(0.0))]}
    preds = {"s": [("divider", tiny, 0.9), ("divider", vline(0.0), 0.8)]}
    fast, ref = evaluate_vectors(gts, preds), reference_evaluate(gts, preds)
    assert ap_of(fast) == pytest.approx(ap_of(ref), abs=1e-12)
    assert ap_of(fast) == pytest.approx([0.25] * 3, abs=1e-12)  # FP (tiny), TP over 2 GTs


def test_prediction_with_exactly_n_points_is_not_resampled():
    """MapTR keeps a 100-point prediction as is: clustered points then give a large CD."""
    clustered = np.concatenate([vline(0.0, 0.0, 1.0, 99), [[0.0, 20.0]]])
    gts = {"s": [("divider", vline(0.0, 0.0, 20.0, 2))]}
    assert ap_of(evaluate_vectors(gts, {"s": [("divider", clustered, 0.9)]})) == [0.0, 0.0, 0.0]
    resampled = clustered[1:]  # 99 points: resampled by arc length onto the whole line
    assert ap_of(evaluate_vectors(gts, {"s": [("divider", resampled, 0.9)]})) == [1.0, 1.0, 1.0]


def test_short_predictions_dropped_and_counted():
    gts = {"s": [("divider", vline(0.0))]}
    r = evaluate_vectors(gts, {"s": [("divider", np.zeros((1, 2)), 0.9), ("divider", vline(0.0), 0.5)]})
    assert r["n_predictions_dropped"] == 1 and r["num_preds"]["divider"] == 1
    assert ap_of(r) == [1.0, 1.0, 1.0]


def test_gt_as_prediction_scores_map_one():
    """Sparse GT vertices as predictions score 1 (hustvl/MapTR#66); all scores tie."""
    gts, _ = synthetic_dataset(20, seed=3)
    preds = {t: [(c, p, 1.0) for c, p in v] for t, v in gts.items()}
    assert evaluate_vectors(gts, preds)["mAP"] == pytest.approx(1.0, abs=1e-12)


def test_shuffled_samples_and_vectors_give_identical_result():
    gts, preds = synthetic_dataset(40, seed=5)
    rng = random.Random(0)
    tied = {t: [(c, p, round(s, 1)) for c, p, s in v] for t, v in preds.items()}  # many exact ties
    base = evaluate_vectors(gts, tied)
    keys = list(tied)
    rng.shuffle(keys)
    shuffled = {}
    for t in keys:
        vecs = list(tied[t])
        rng.shuffle(vecs)
        shuffled[t] = vecs
    gkeys = list(gts)
    rng.shuffle(gkeys)
    again = evaluate_vectors({t: gts[t] for t in gkeys}, shuffled)
    assert again == base
    assert 0.2 < base["mAP"] < 0.95


def test_voc_area_ap_matches_hand_values():
    assert voc_area_ap(np.array([1.0, 0.0, 1.0]), np.array([0.0, 1.0, 0.0]), 2) == pytest.approx(5 / 6)
    assert voc_area_ap(np.array([]), np.array([]), 3) == 0.0
    assert voc_area_ap(np.array([0.0]), np.array([1.0]), 0) == 0.0


# --- agreement with the per-sample reference -------------------------------------------------


def _random_line(draw, n_max: int = 12) -> np.ndarray:
    kind = draw(st.sampled_from(["walk", "short", "ring", "zigzag", "degenerate"]))
    x0, y0 = draw(st.floats(-15, 15)), draw(st.floats(-30, 30))
    n = draw(st.integers(2, n_max))
    seed = draw(st.integers(0, 2**31))
    rng = np.random.default_rng(seed)
    if kind == "walk":
        pts = np.cumsum(rng.normal(0, 3, (n, 2)), axis=0)
    elif kind == "short":
        pts = np.cumsum(rng.normal(0, 0.05, (n, 2)), axis=0)
    elif kind == "ring":
        w, h = rng.uniform(0.5, 8, 2)
        pts = np.array([[0, 0], [w, 0], [w, h], [0, h], [0, 0]])
    elif kind == "zigzag":
        pts = np.stack([np.arange(n) * rng.uniform(0.1, 2), (np.arange(n) % 2) * rng.uniform(0.1, 3)], 1)
    else:
        pts = np.zeros((n, 2))
    return pts + [x0, y0]


@st.composite
def eval_cases(draw):
    gts, preds = {}, {}
    for s in range(draw(st.integers(1, 4))):
        g = [(draw(st.sampled_from(CLASSES[:2])), _random_line(draw)) for _ in range(draw(st.integers(0, 5)))]
        p = []
        for c, line in g:
            if draw(st.booleans()):
                noise = draw(st.floats(0, 1.5))
                jitter = np.random.default_rng(draw(st.integers(0, 2**31))).normal(0, noise, line.shape)
                p.append((c, line + jitter, draw(st.sampled_from([0.1, 0.5, 0.9, 0.33]))))
        for _ in range(draw(st.integers(0, 4))):
            p.append((draw(st.sampled_from(CLASSES[:2])), _random_line(draw), draw(st.floats(0, 1))))
        gts[f"tok{s}"] = g
        preds[f"tok{s}"] = p
    return gts, preds


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(eval_cases())
def test_agrees_with_reference_implementation(case):
    gts, preds = case
    fast = evaluate_vectors(gts, preds)
    ref = reference_evaluate(gts, preds)
    assert np.abs(all_aps(fast) - all_aps(ref)).max() <= 1e-9
    assert abs(fast["mAP"] - ref["mAP"]) <= 1e-9
    assert fast["num_gts"] == ref["num_gts"] and fast["num_preds"] == ref["num_preds"]


def test_agrees_with_reference_on_realistic_data():
    gts, preds = synthetic_dataset(30, seed=11)
    fast, ref = evaluate_vectors(gts, preds), reference_evaluate(gts, preds)
    assert np.abs(all_aps(fast) - all_aps(ref)).max() <= 1e-9
    assert fast["stats"]["close_pairs"] > 0


def test_city_scale_coordinates_agree():
    gts, preds = synthetic_dataset(5, seed=2)
    off = np.array([4.5e5, 5.2e6])
    gts = {t: [(c, p + off) for c, p in v] for t, v in gts.items()}
    preds = {t: [(c, p + off, s) for c, p, s in v] for t, v in preds.items()}
    fast, ref = evaluate_vectors(gts, preds), reference_evaluate(gts, preds)
    assert np.abs(all_aps(fast) - all_aps(ref)).max() <= 1e-9
    assert np.isfinite(fast["mAP"])


def test_sure_candidate_test_never_contradicts_geos():
    """The numba shortcut may say "unsure", but its "intersect" must agree with GEOS buffers."""
    rng = np.random.default_rng(7)
    lines = []
    for i in range(600):
        kind = i % 4
        n = int(rng.integers(2, 12))
        base = rng.uniform(-3, 3, 2)
        if kind == 0:
            pts = base + np.cumsum(rng.normal(0, 1.5, (n, 2)), axis=0)
        elif kind == 1:
            pts = base + np.cumsum(rng.normal(0, 0.1, (n, 2)), axis=0)
        elif kind == 2:
            w, h = rng.uniform(0.3, 4, 2)
            pts = base + np.array([[0, 0], [w, 0], [w, h], [0, h], [0, 0]])
        else:
            pts = base + np.stack([np.arange(n) * 0.4, (np.arange(n) % 2) * 2.5], 1)
        lines.append(pts)
    n = len(lines)
    lines += [line + rng.normal(0, 0.5, 2) + rng.normal(0, 0.2, line.shape) for line in lines]  # close copies
    pts = resample_polylines(lines, 100)
    a = np.concatenate([rng.integers(0, 2 * n, 4000), np.arange(n)])
    b = np.concatenate([rng.integers(0, 2 * n, 4000), np.arange(n) + n])
    sure = np.zeros(len(a), dtype=bool)
    _sure_candidate_kernel(pts, pts, a, b, BUFFER_M, _SURE_MARGIN_M, sure)
    buf = shapely.buffer(
        shapely.linestrings(pts), BUFFER_M, quad_segs=16, cap_style="flat", join_style="mitre"
    )
    geos = shapely.intersects(buf[a], buf[b])
    assert not np.any(sure & ~geos)
    close_pairs = slice(4000, None)  # it exists to decide the pairs of a line and its noisy copy
    assert sure[close_pairs].sum() > 0.8 * geos[close_pairs].sum()


def test_resampling_matches_shapely_interpolate():
    rng = np.random.default_rng(1)
    lines = [rng.normal(0, 10, (int(rng.integers(2, 30)), 2)) for _ in range(200)]
    lines += [
        np.array([[1.0, 2.0], [1.0, 2.0]]),
        np.array([[0.0, 0], [0, 0], [1, 0], [1, 0], [3, 0]]),
        np.array([[5e5, 4e6], [5e5 + 1e-3, 4e6]]),
    ]
    ours = resample_polylines(lines, 100)
    for line, got in zip(lines, ours):
        ls = shapely.LineString(line)
        want = shapely.get_coordinates(shapely.line_interpolate_point(ls, np.linspace(0, ls.length, 100)))
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-9 * max(1.0, np.abs(line).max()))
        np.testing.assert_array_equal(got[0], line[0])
        np.testing.assert_array_equal(got[-1], line[-1])


# --- bad input and files ---------------------------------------------------------------------


def test_bad_inputs_raise_clear_errors():
    gts = {"s": [("divider", vline(0.0))]}
    with pytest.raises(ValueError, match="not in the GT set"):
        evaluate_vectors(gts, {"other": []})
    with pytest.raises(ValueError, match="sample s: prediction vector 0 .*NaN"):
        evaluate_vectors(gts, {"s": [("divider", np.array([[0.0, np.nan], [1, 1]]), 0.5)]})
    with pytest.raises(ValueError, match=r"shape \(N, 2\)"):
        evaluate_vectors(gts, {"s": [("divider", np.zeros((3, 3)), 0.5)]})
    with pytest.raises(ValueError, match="non-finite score"):
        evaluate_vectors(gts, {"s": [("divider", vline(0.0), float("nan"))]})
    with pytest.raises(ValueError, match="thresholds"):
        evaluate_vectors(gts, {}, thresholds=(0.5, 150.0))


def test_prediction_file_formats(tmp_path):
    gts = {"a": [("divider", vline(0.0))], "b": [("boundary", vline(3.0))]}
    vec = {
        "pts": vline(0.0).tolist(),
        "pts_num": 5,
        "cls_name": "divider",
        "type": 0,
        "confidence_level": 0.8,
    }
    as_list = {
        "meta": {},
        "results": [{"sample_token": "a", "vectors": [vec]}, {"sample_token": "b", "vectors": []}],
    }
    as_dict = {"meta": {}, "results": {"b": [], "a": [vec]}}
    (tmp_path / "l.json").write_text(json.dumps(as_list))
    (tmp_path / "d.json").write_text(json.dumps(as_dict))
    r1 = evaluate_vectors(gts, load_predictions(tmp_path / "l.json"))
    r2 = evaluate_vectors(gts, load_predictions(tmp_path / "d.json"))
    assert r1 == r2 and r1["ap"]["divider"]["0.5"] == 1.0 and r1["ap"]["boundary"]["0.5"] == 0.0
    (tmp_path / "gt.json").write_text(
        json.dumps(
            {
                "GTs": [
                    {
                        "sample_token": "a",
                        "vectors": [
                            {"pts": vline(0.0).tolist(), "pts_num": 5, "cls_name": "divider", "type": 0}
                        ],
                    }
                ]
            }
        )
    )
    assert load_gt_file(tmp_path / "gt.json")["a"][0][0] == "divider"
    (tmp_path / "bad.json").write_text(
        json.dumps(
            {
                "results": [
                    {"sample_token": "a", "vectors": [{"pts": [[0, 0], [1, 1]], "cls_name": "divider"}]}
                ]
            }
        )
    )
    with pytest.raises(ValueError, match="bad.json.*confidence_level"):
        load_predictions(tmp_path / "bad.json")
    (tmp_path / "dup.json").write_text(json.dumps({"results": [{"sample_token": "a", "vectors": []}] * 2}))
    with pytest.raises(ValueError, match="dup.json: sample_token a appears twice"):
        load_predictions(tmp_path / "dup.json")
    with pytest.raises(FileNotFoundError, match="missing.json"):
        load_predictions(tmp_path / "missing.json")


# --- CLI -------------------------------------------------------------------------------------


def test_eval_cli_with_gt_file(tmp_path, capsys):
    from nuav2.cli import main

    gts, preds = synthetic_dataset(6, seed=4)
    gt_file, pred_file, out = tmp_path / "gt.json", tmp_path / "pred.json", tmp_path / "res" / "r.json"
    gt_file.write_text(
        json.dumps(
            {
                "GTs": [
                    {
                        "sample_token": t,
                        "vectors": [{"pts": p.tolist(), "pts_num": len(p), "cls_name": c} for c, p in v],
                    }
                    for t, v in gts.items()
                ]
            }
        )
    )
    pred_file.write_text(
        json.dumps(
            {
                "meta": {},
                "results": [
                    {
                        "sample_token": t,
                        "vectors": [
                            {"pts": p.tolist(), "pts_num": len(p), "cls_name": c, "confidence_level": s}
                            for c, p, s in v
                        ],
                    }
                    for t, v in preds.items()
                ],
            }
        )
    )
    assert main(["eval", str(pred_file), "--gt-json", str(gt_file), "--json", "--out", str(out)]) == 0
    printed = json.loads(capsys.readouterr().out)
    want = evaluate_vectors(gts, preds)
    assert printed["mAP"] == pytest.approx(want["mAP"], abs=1e-12)
    assert json.loads(out.read_text())["ap"] == printed["ap"]
    assert main(["eval", str(pred_file), "--gt-json", str(gt_file)]) == 0
    headline = "mAP (headline) over 4 classes (divider, ped_crossing, boundary, centerline)"
    assert headline in capsys.readouterr().out
    other_gt = tmp_path / "other.json"
    other_gt.write_text(json.dumps({"GTs": []}))
    assert main(["eval", str(pred_file), "--gt-json", str(other_gt)]) == 2
    assert "pred.json" in capsys.readouterr().err


def test_bench_eval_cli_small(capsys):
    from nuav2.cli import main

    assert main(["bench", "eval", "--samples", "12", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["n_samples"] == 12 and out["n_pred_vectors"] >= 12 * 50
    assert out["max_ap_abs_diff"] <= 1e-9 and out["speedup"] > 0


def test_eval_cli_builds_gt_from_the_map(tmp_path, capsys):
    """End to end with the real devkit map: the GT itself as predictions scores 1 on its classes."""
    from tiny_nuscenes_db import VERSION, write_tiny_db

    from nuav2.cli import main
    from nuav2.maptr.vectorize import gt_vectors_for_split

    root = write_tiny_db(tmp_path / "db")
    (root / VERSION / "splits.json").write_text(json.dumps({"train": [], "val": ["scene-0001"]}))
    gts = gt_vectors_for_split(root, VERSION, "val")
    assert len(gts) == 3 and any(gts.values())
    results = [
        {
            "sample_token": t,
            "vectors": [
                {"pts": p.tolist(), "pts_num": len(p), "cls_name": c, "confidence_level": 1.0} for c, p in v
            ],
        }
        for t, v in gts.items()
    ]
    pred = tmp_path / "pred.json"
    pred.write_text(json.dumps({"meta": {}, "results": results}))
    args = ["eval", str(pred), "--dataroot", str(root), "--version", VERSION, "--split", "val", "--json"]
    assert main(args) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["n_samples"] == 3 and out["n_samples_without_predictions"] == 0
    assert sorted(out["classes"] + out["classes_left_out"]) == sorted(CLASSES)  # left out: no GT to copy
    with_gt = [c for c in out["classes"] if out["num_gts"][c] > 0]
    assert with_gt and all(out["class_mean_ap"][c] == pytest.approx(1.0, abs=1e-12) for c in with_gt)
    assert all(v == pytest.approx(1.0, abs=1e-12) for v in out["map_per_threshold"].values())
    results.append({"sample_token": "f" * 32, "vectors": []})
    pred.write_text(json.dumps({"meta": {}, "results": results}))
    assert main(args) == 2
    assert "not in the GT set" in capsys.readouterr().err


def test_repeated_thresholds_are_refused_rather_than_counted_twice_in_map():
    gts = {"t": [("divider", np.array([[0.0, 0.0], [10.0, 0.0]]))]}
    preds = {"t": [("divider", np.array([[0.0, 0.8], [10.0, 0.8]]), 0.9)]}
    with pytest.raises(ValueError, match=r"thresholds must be distinct, got \[0.5, 0.5, 1.5\]"):
        evaluate_vectors(gts, preds, classes=("divider",), thresholds=(0.5, 0.5, 1.5))
    assert evaluate_vectors(gts, preds, classes=("divider",), thresholds=(0.5, 1.5))["mAP"] == 0.5


def test_a_non_finite_prediction_is_named_by_its_own_index_after_a_dropped_one():
    gts = {"t": [("divider", np.array([[0.0, 0.0], [1.0, 0.0]]))]}
    preds = {"t": [("divider", np.array([[5.0, 5.0]]), 0.9),  # one point: dropped
                   ("divider", np.array([[0.0, 0.0], [np.nan, 0.0]]), 0.8)]}
    with pytest.raises(ValueError, match=r"sample t: prediction vector 1 \(divider\) has NaN or Inf"):
        evaluate_vectors(gts, preds)
