"""`nuav2 bench raster` end to end on a tiny case: valid JSON with every reported figure present."""

from __future__ import annotations

import json
import math

from nuav2.cli import main


def test_bench_raster_cli_reports_every_figure(capsys):
    assert main(["bench", "raster", "--sizes", "64x40", "--counts", "1500", "--repeats", "1", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["bench"] == "raster" and report["threads"] >= 1
    (case,) = report["cases"]
    assert (case["w"], case["h"], case["n"]) == (64, 40, 1500)
    assert 0 < case["visible"] <= 1500
    for key in ("fwd_s", "fwdbwd_s", "fwd_s_min", "fwdbwd_s_min"):
        assert math.isfinite(case[key]) and case[key] > 0
    assert case["fwdbwd_s"] >= case["fwd_s_min"]
    assert case["peak_rss_mb"] >= 0
    dense = case["dense"]
    assert dense["crop_w"] == dense["crop_h"] <= 40
    assert dense["visible_in_crop"] > 0
    assert case["speedup_vs_dense"] == dense["speedup_vs_dense"] > 0
