"""``nuav2 bench recon`` over presets and seeds: region scores per row, the tuned seed kept apart, mean and
spread over the other seeds (timings are reported, never asserted)."""

from __future__ import annotations

import pytest

from nuav2.bench.recon import TUNED, bench_recon, over_seeds

TINY_SYNTH = {"seconds": 0.3, "image_scale": 1 / 16, "lidar_azimuth_steps": 256, "n_parked": 2, "n_moving": 1,
              "n_pedestrians": 0, "map_margin_m": 30.0}
SEED_ONLY = {"name": "init-only", "iterations": 0, "gaussians": 8_000, "train_width_px": 64}


def _row(seed: int, psnr: float, tuned: bool = False) -> dict:
    regions = {"psnr_db": {"whole": psnr, "ground": psnr - 1, "objects": None, "sky": psnr + 2},
               "ssim": {"whole": 0.8, "ground": 0.7, "objects": None, "sky": 0.9}}
    return {"preset": "easy", "name": "fast", "seed": seed, "tuned": tuned, "recon_s": 10.0,
            "recon_cpu_s": 20.0, "render_log_s": 4.0, "frames": 20,
            "target": {"regions": regions, "paint": {"median_px_render": 1.0, "median_px_truth": 0.9}}}


def test_over_seeds_keeps_the_tuned_seed_apart():
    rows = [_row(0, 30.0, tuned=True), _row(1, 24.0), _row(2, 26.0), _row(3, 25.0)]
    (entry,) = over_seeds(rows)
    assert entry["seeds"] == [1, 2, 3] and entry["tuned_seed"]["seed"] == 0
    assert entry["tuned_seed"]["psnr_whole"] == 30.0
    whole = entry["untuned"]["psnr_whole"]
    assert whole["mean"] == pytest.approx(25.0) and whole["std"] == pytest.approx(1.0)
    assert (whole["min"], whole["max"]) == (24.0, 26.0)
    assert entry["untuned"]["psnr_ground"]["mean"] == pytest.approx(24.0)
    assert "psnr_objects" not in entry["untuned"]  # no image had objects: nothing to average
    assert entry["untuned"]["render_s_per_frame"]["mean"] == pytest.approx(0.2)
    (single,) = over_seeds([_row(5, 20.0)])
    assert single["untuned"]["psnr_whole"]["std"] is None and "tuned_seed" not in single


def test_bench_recon_over_two_seeds_scores_regions_and_marks_the_tuned_seed():
    result = bench_recon(seeds=(0, 1), presets=("easy",), budgets=[SEED_ONLY], n_times=2,
                         synth_overrides=TINY_SYNTH, command="nuav2 bench recon (test)")
    assert ("easy", 0) in TUNED and result["tuned_on"] == [{"preset": "easy", "seed": 0}]
    rows = result["rows"]
    assert [(r["seed"], r["tuned"]) for r in rows] == [(0, True), (1, False)]
    for r in rows:
        regions = r["target"]["regions"]
        assert set(regions["psnr_db"]) == {"whole", "ground", "objects", "sky", "nonrigid"}
        assert regions["psnr_db"]["whole"] == pytest.approx(r["target"]["psnr_db"])
        assert 5.0 < regions["psnr_db"]["ground"] < 60.0 and r["recon_cpu_s"] > 0
        assert r["frames"] == 3 and r["target"]["images"] == 2 * 6
    (entry,) = result["over_seeds"]
    assert entry["seeds"] == [1] and entry["tuned_seed"]["seed"] == 0
    assert entry["untuned"]["psnr_whole"]["mean"] == pytest.approx(rows[1]["target"]["psnr_db"])
    assert result["command"] == "nuav2 bench recon (test)"
    assert len(result["machine_at_start"]["load_1_5_15"]) == 3
    from nuav2.bench.markdown import recon_markdown

    text = recon_markdown(result)
    assert "`nuav2 bench recon (test)`" in text
    assert "seed 0 (the seed the reconstruction presets were tuned on)" in text
    assert "| easy | init-only | 1 |" in text


def test_bench_recon_scenes_empty_road_gets_a_smaller_budget_than_a_busy_junction():
    """``--scene empty,busy``: the scene budget follows the scene (a straight road without traffic against
    a junction with traffic); each row reports its budget, iterations run and held-out source-view PSNR next
    to the target-rig PSNR, and the markdown puts the scenes side by side."""
    from nuav2.bench.markdown import recon_markdown

    tiny = {k: v for k, v in TINY_SYNTH.items() if not k.startswith("n_")}
    result = bench_recon(seeds=(0,), presets=("easy",), budgets=[SEED_ONLY], n_times=1,
                         scenes=("empty", "busy"), synth_overrides=tiny,
                         command="nuav2 bench recon --scene empty,busy (test)")
    empty, busy = result["rows"]
    assert (empty["scene"], busy["scene"]) == ("empty", "busy") and not empty["tuned"]
    assert empty["moving_tracks"] == 0 < busy["moving_tracks"]
    assert empty["scene_budget"] <= busy["scene_budget"]  # (both at the 20k floor on a log this small)
    assert empty["init_s"] > 0 and busy["final_gaussians"] > 0
    assert empty["steps"] == 0 and empty["heldout"]["images"] > 0
    assert 5.0 < empty["heldout"]["psnr_db"] < 60.0 and 5.0 < empty["target"]["psnr_db"] < 60.0
    text = recon_markdown(result)
    assert "Scenes side by side" in text and "| empty | 0 | init-only |" in text
    assert "held-out source PSNR" in text and "Preset `easy, scene busy`, seed 0:" in text
