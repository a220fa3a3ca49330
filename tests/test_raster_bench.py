"""`nuav2 bench raster` end to end on a tiny case: valid JSON with every reported field present and sane.

No timing relation is asserted (timings live in the benchmark, not in tests): only that each
figure exists, is finite and has the right sign, and the accuracy of the two renderers.
"""

from __future__ import annotations

import json
import math

from nuav2.cli import main
from nuav2.splat.gsplat_reference import gsplat_installed

TIMES = ("wall_s_min", "wall_s_median", "cpu_s_min", "cpu_s_median")


def _finite_non_negative(x) -> bool:
    return isinstance(x, (int, float)) and math.isfinite(x) and x >= 0


def test_bench_raster_cli_reports_every_figure(capsys):
    assert main(["bench", "raster", "--sizes", "64x40", "--counts", "1500", "--repeats", "1", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["bench"] == "raster" and report["interleaved"] is True
    threads = report["threads"]
    assert threads >= 1 and report["repeats"] == 1
    assert report["roofline_evals_per_s"] > 0 and report["roofline_evals_per_cpu_s"] > 0
    assert len(report["load_avg_1m"]) == 2
    assert {c["scene"] for c in report["cases"]} == {"street", "near_splats"}
    for case in report["cases"]:
        assert (case["w"], case["h"], case["n"]) == (64, 40, 1500)
        assert case["contributions"] > 0 and case["depth_slabs"] >= 1
        assert 0 < case["tile_pairs"] <= case["tile_pairs_without_slabs"]
        assert case["contributions_per_pixel"] == round(case["contributions"] / (64 * 40), 2)
        for name in ("ours_1_thread", f"ours_{threads}_threads"):
            assert all(_finite_non_negative(case[name][k]) for k in TIMES), name
            assert case[name]["steps"] == 1 and _finite_non_negative(case[name]["peak_rss_mb"])
        assert set(case["stages_ms"]) >= {"projection_fwd", "sort", "binning", "composite_fwd",
                                          "composite_bwd", "projection_bwd"}
        assert all(_finite_non_negative(v["wall"]) and _finite_non_negative(v["cpu"])
                   for v in case["stages_ms"].values())
        for key in ("speedup_threads_vs_1", "ns_per_contribution", "cpu_ns_per_contribution", "floor_s",
                    "roofline_fraction", "floor_cpu_s", "roofline_fraction_cpu"):
            assert _finite_non_negative(case[key]), key
        assert len(case["load_avg_1m"]) == 2
        if gsplat_installed():
            assert report["gsplat_reference"] is True
            assert all(_finite_non_negative(case["gsplat_torch"][k]) for k in TIMES)
            assert case["vs_gsplat"]["rgb_max_abs"] < 1e-5 and case["vs_gsplat"]["alpha_max_abs"] < 1e-5
            assert case["vs_gsplat"]["depth_max_rel"] < 1e-5
            assert _finite_non_negative(case["speedup_vs_gsplat_torch"])
        else:
            assert "skipped" in case["gsplat_torch"]


def test_cli_scene_names_are_the_bench_scenes():
    from nuav2.bench.raster import SCENES
    from nuav2.commands.bench_raster import SCENES as CLI_SCENES

    assert set(CLI_SCENES) == set(SCENES)
