"""``nuav2 bench modes`` on a tiny synthetic log: every candidate scored per region, timed interleaved,
the amortised figures consistent with their parts (no timing relation is asserted)."""

from __future__ import annotations

import numpy as np
import pytest

from nuav2.bench.modes import TIMED, bench_one_log, mean_colour_image, side_by_side
from nuav2.cli import main
from nuav2.recon import ReconConfig
from nuav2.splat.densify import DensifyConfig
from nuav2.splat.init import InitConfig
from nuav2.splat.train import TrainConfig
from nuav2.synth import REGION_LABELS

TINY_SYNTH = {"image_scale": 1 / 16, "lidar_azimuth_steps": 256, "n_parked": 2, "n_moving": 1,
              "n_pedestrians": 0, "map_margin_m": 30.0}
TINY_RECON = ReconConfig(train_width_px=128, frame_stride=2,
                         init=InitConfig(max_background=8_000, ground_spacing_m=0.5, ground_radius_m=12.0),
                         train=TrainConfig(iterations=30, pyramid=(1.0,), pyramid_until=(),
                                           densify=DensifyConfig(start=1000, every=1000, stop=0,
                                                                 budget=10_000)))


@pytest.fixture(scope="module")
def run():
    return bench_one_log("easy", 0.3, seed=2, scale=0.1, recon_config=TINY_RECON, synth_overrides=TINY_SYNTH,
                         progress=False)


def test_every_candidate_is_scored_per_region(run):
    modes = run["modes"]
    assert set(modes) == {*TIMED, "mean_colour"} and run["frames"] == 3 and run["render_status"] == "ok"
    for m, v in modes.items():
        q = v["quality"]
        assert q["images"] == 3 * 6, m
        assert set(q["per_camera"]) == set(run["target"]["cameras"])
        for region in ("whole", "ground", "sky"):
            assert q["psnr_db"][region] is not None and np.isfinite(q["psnr_db"][region]), (m, region)
            assert -1.0 <= q["ssim"][region] <= 1.0
    whole = {m: v["quality"]["psnr_db"]["whole"] for m, v in modes.items()}
    # The order the docs report: the warp well above the rotation baseline, which is above a flat image.
    assert whole["warp"] > whole["rotation"] + 4.0
    assert whole["rotation"] > whole["mean_colour"]
    assert run["ratios"]["warp_minus_rotation_psnr_db"] == pytest.approx(whole["warp"] - whole["rotation"],
                                                                          abs=1e-3)


def test_timings_are_interleaved_per_frame_and_amortised_from_their_parts(run):
    n = run["frames"]
    for m in TIMED:
        pf = run["modes"][m]["per_frame"]
        assert pf["n"] == n and pf["wall_s_mean"] > 0 and pf["cpu_s_mean"] > 0
        assert len(pf["load_1min"]) == 2
    assert "per_frame" not in run["modes"]["mean_colour"]  # scored, never timed
    for m in ("warp", "render"):
        v = run["modes"][m]
        for clock in ("wall", "cpu"):
            want = v["per_frame"][f"{clock}_s_mean"] + v["setup"][f"{clock}_s"] / n
            assert v["amortised_per_frame"][f"{clock}_s"] == pytest.approx(want, abs=0.01)
    r = run["ratios"]
    w, rd = run["modes"]["warp"], run["modes"]["render"]
    assert r["render_over_warp_per_frame_cpu"] == pytest.approx(
        rd["per_frame"]["cpu_s_mean"] / w["per_frame"]["cpu_s_mean"], rel=0.02)
    rows = side_by_side([run])
    assert len(rows) == 5 and {row["mode"] for row in rows} == {*TIMED, "mean_colour"}
    assert all("psnr_ground" in row and "ssim_ground" in row and "paint_px" in row for row in rows)


def test_mean_colour_floor_ignores_the_ego_body():
    truth = np.zeros((4, 4, 3), np.uint8)
    truth[:2] = 200
    labels = np.full((4, 4), REGION_LABELS["ground"], np.uint8)
    labels[:2] = REGION_LABELS["ego"]
    truth[2:] = (10, 20, 30)
    flat = mean_colour_image(truth, labels)
    assert flat.dtype == np.uint8 and np.all(flat == (10, 20, 30))


def test_unknown_preset_and_bad_seconds_are_one_line_errors(capsys):
    assert main(["bench", "modes", "--preset", "nope", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "--preset: unknown preset(s) ['nope']; known: easy, medium, hard" in err
    assert len(err.splitlines()) == 1
    assert main(["bench", "modes", "--seconds", "2,x", "--quiet"]) == 2
    assert "--seconds: expected comma-separated numbers" in capsys.readouterr().err
    assert main(["bench", "recon", "--budgets", "fast,huge"]) == 2
    assert "--budgets: unknown budget(s) ['huge']" in capsys.readouterr().err
    assert main(["demo", "--preset", "easy,extreme"]) == 2
    assert "--preset: unknown preset(s) ['extreme']" in capsys.readouterr().err


def test_markdown_tables_say_how_they_were_measured(run):
    from nuav2.bench.markdown import modes_markdown

    result = {"command": "nuav2 bench modes (test)", "machine_at_start": {"load_1_5_15": [1.0, 1.0, 1.0],
                                                                         "cpu_count": 2},
              "load_1_5_15_at_end": [1.5, 1.0, 1.0], "runs": [run]}
    text = modes_markdown(result)
    assert "`nuav2 bench modes (test)`" in text and "interleaved frame by frame" in text and "load" in text
    assert "| rotation mosaic |" in text and "| mean colour |" in text and "| easy, 0.3 s | 3 |" in text
    warp_row = next(line for line in text.splitlines() if line.startswith("| warp |"))
    assert f"{run['modes']['warp']['quality']['psnr_db']['ground']:.2f}" in warp_row
    # a second seed: cells become mean ± std over the seeds, timing rows name the seed
    import copy

    other = copy.deepcopy(run)
    other["seed"] = run["seed"] + 1
    ground = run["modes"]["warp"]["quality"]["psnr_db"]["ground"]
    other["modes"]["warp"]["quality"]["psnr_db"]["ground"] = ground + 2
    two = modes_markdown({**result, "runs": [run, other]})
    warp_row = next(line for line in two.splitlines() if line.startswith("| warp |"))
    assert f"{ground + 1:.2f} ± 1.00" in warp_row and "mean ± std over seeds" in two
    assert f"| easy, 0.3 s, seed {other['seed']} |" in two


def test_markdown_rows_fill_their_header_and_no_render_keeps_the_timings(run):
    """Found by review: the paint-floor row had one cell too few (its value under 'SSIM ground'), and
    with --no-render the rotation and warp timings were left out of the markdown."""
    import copy

    from nuav2.bench.markdown import modes_markdown

    result = {"command": "nuav2 bench modes (test)", "machine_at_start": {"load_1_5_15": [1.0, 1.0, 1.0],
                                                                         "cpu_count": 2},
              "load_1_5_15_at_end": [1.5, 1.0, 1.0]}
    no_render = copy.deepcopy(run)
    no_render["modes"].pop("render", None)
    no_render.pop("ratios", None)
    for runs in ([run], [no_render]):
        text = modes_markdown({**result, "runs": runs})
        tables = [block.splitlines() for block in text.split("\n\n") if block.startswith("|")]
        assert len(tables) == 2, text  # quality and time
        for table in tables:
            widths = {line.count("|") for line in table}
            assert len(widths) == 1, table
        floor = next(line for line in text.splitlines() if line.startswith("| ground truth (paint floor)"))
        assert floor.split("|")[-2].strip() != "–"
        warp_time = f"{run['modes']['warp']['per_frame']['wall_s_mean']:.3f}"
        assert warp_time in tables[1][2], tables[1]
