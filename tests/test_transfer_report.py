"""Table logic of ``nuav2 bench transfer``: means and spreads over seeds, ratios next to the paper's,
and verdicts that flip when the ordering does."""

from __future__ import annotations

import pytest

from nuav2.bench.transfer_config import TransferConfig
from nuav2.bench.transfer_report import format_tables, summarize

CLASSES = ["divider", "ped_crossing", "boundary", "centerline"]


def _eval(m: float) -> dict:
    """An eval result whose every AP is ``m`` except centerline (0), so mAP = 0.75 m."""
    ap = {c: {t: (0.0 if c == "centerline" else m) for t in ("0.5", "1.0", "1.5")} for c in CLASSES}
    return {
        "ap": ap,
        "class_mean_ap": {c: ap[c]["0.5"] for c in CLASSES},
        "mAP": 0.75 * m,
        "map_per_threshold": {},
        "num_gts": {},
        "num_preds": {},
        "n_samples": 10,
    }


def _result(maps: dict[str, list[float]], ft: dict[tuple[float, str], list[float]] | None = None) -> dict:
    cfg = TransferConfig.for_size("quick", fractions=tuple(sorted({f for f, _ in (ft or {})})))
    runs = {}
    for s, values in maps.items():
        for seed, m in zip(cfg.seeds, values):
            runs[f"{s}-s{seed}"] = {"set": s, "seed": seed, "keyframes": 60, "scenes": 4, "eval": _eval(m),
                                      "bev_seg": {"ap": m / 2}}
    for (f, arm), values in (ft or {}).items():
        for seed, m in zip(cfg.seeds, values):
            runs[f"ft{f}-{arm}-s{seed}"] = {
                "fraction": f,
                "arm": arm,
                "seed": seed,
                "keyframes": 15,
                "scenes": 1,
                "eval": _eval(m),
                "bev_seg": {"ap": m / 2},
            }
    return {"config": cfg.to_dict(), "runs": runs}


def test_means_spreads_and_ratios():
    r = _result({"native": [0.1, 0.3], "warp": [0.3, 0.5], "render": [0.4, 0.4], "truth": [0.8, 0.8]})
    s = summarize(r)
    assert s["table1"]["native"]["mAP"]["mean"] == pytest.approx(0.15)
    assert s["table1"]["native"]["mAP"]["std"] == pytest.approx(0.75 * 0.2 / 2**0.5)
    assert s["table1"]["truth"]["class_mean_ap"]["centerline"]["mean"] == 0.0
    ratio = s["ratios"]["render_over_av2"]
    assert ratio["of_means"] == pytest.approx(0.4 / 0.2) and ratio["paper"] == 4.25
    assert ratio["per_seed"] == {"0": pytest.approx(4.0), "1": pytest.approx(4.0 / 3)}
    assert s["ratios"]["render_over_oracle"]["of_means"] == pytest.approx(0.5)
    v = s["verdict"]["oracle_gt_render_gt_av2"]
    assert v["on_means"] and v["seeds_holding"] == 2
    w = s["verdict"]["oracle_gt_warp_gt_av2"]
    assert w["on_means"] and w["seeds_holding"] == 2
    assert v["bev_seg_ap_on_means"] and s["table1"]["truth"]["bev_seg_ap"]["mean"] == pytest.approx(0.4)


def test_the_verdict_says_when_the_ordering_fails():
    r = _result(
        {"native": [0.5, 0.5], "render": [0.4, 0.6], "truth": [0.8, 0.8]},
        {(0.25, "scratch"): [0.5, 0.5], (0.25, "pretrained"): [0.4, 0.6]},
    )
    r["config"]["sets"] = ["native", "render", "truth"]
    s = summarize(r)
    v = s["verdict"]["oracle_gt_render_gt_av2"]
    assert not v["on_means"] and v["seeds_holding"] == 1
    p = s["verdict"]["pretraining_helps"]["0.25"]
    assert not p["holds"] and p["seeds_holding"] == 1 and p["gain_mAP"] == pytest.approx(0.0)
    text = format_tables({**r, **s, "prior_only": {}})
    assert "does NOT hold" in text and "does NOT help" in text and "4.25x" in text and "29 %" in text
    assert "not measurable" not in text


def test_differences_below_the_tables_resolution_are_ties():
    s = summarize(
        _result(
            {"native": [0.0, 0.0], "render": [0.0004, 0.0], "truth": [0.0008, 0.0]},
            {(0.25, "scratch"): [0.0, 0.0], (0.25, "pretrained"): [0.0004, 0.0004]},
        )
    )
    v, p = s["verdict"]["oracle_gt_render_gt_av2"], s["verdict"]["pretraining_helps"]["0.25"]
    assert not v["on_means"] and not v["measurable"] and not p["holds"] and not p["measurable"]


def test_a_zero_baseline_gives_no_ratio():
    s = summarize(_result({"native": [0.0, 0.0], "render": [0.2, 0.2], "truth": [0.4, 0.4]}))
    assert s["ratios"]["render_over_av2"]["of_means"] is None


def test_each_decoding_has_its_own_tables_and_verdict():
    """The vector head's and the segmentation-traced scores are summarised apart: here the ordering
    holds on one and fails on the other, and the printed tables say which is which."""
    r = _result({"native": [0.1, 0.1], "render": [0.2, 0.2], "truth": [0.4, 0.4]})
    r["config"]["sets"] = ["native", "render", "truth"]
    for run in r["runs"].values():  # the traced decoding ranks AV2 first
        run["eval_seg"] = _eval({"native": 0.3, "render": 0.2, "truth": 0.1}[run["set"]])
    vector, seg = summarize(r), summarize(r, "eval_seg")
    assert vector["verdict"]["oracle_gt_render_gt_av2"]["on_means"]
    assert not seg["verdict"]["oracle_gt_render_gt_av2"]["on_means"]
    assert seg["table1"]["native"]["mAP"]["mean"] == pytest.approx(0.75 * 0.3)
    text = format_tables({**r, **vector, "seg_decoded": seg, "prior_only": {}})
    head, traced = text.split("### Decoded by polylines traced from the BEV segmentation")
    assert "### Decoded by the vector head" in head and "oracle > nuAV2 (render) > AV2: holds" in head
    assert "oracle > nuAV2 (render) > AV2: does NOT hold" in traced
