"""``nuav2 bench ablation`` on a tiny run: rows, costs against easy, the docs' table and a picture."""

from __future__ import annotations

import json

import cv2
import pytest

from nuav2.bench.ablation import AblationOptions, ablation_rows, bench_ablation, markdown_table
from nuav2.cli import main as cli_main
from nuav2.synth import FACTORS


def test_rows_are_easy_each_factor_alone_then_the_presets():
    rows = ablation_rows(AblationOptions())
    assert [name for name, _ in rows] == ["easy", *(f"+{f}" for f in FACTORS), "+exposure_gains", "medium",
                                          "hard"]
    assert rows[0][1].factors == frozenset()
    for (name, cfg), f in zip(rows[1:], FACTORS):
        assert cfg.factors == {f} and cfg.preset == "easy" and cfg.camera_noise, name
    gains = dict(rows)["+exposure_gains"]
    assert gains.factors == {"exposure"} and not gains.camera_noise
    assert rows[-1][1].factors == frozenset(FACTORS)


def test_exposure_costs_warp_and_the_table_says_how_it_was_measured(tmp_path):
    opts = AblationOptions(seeds=(0,), factors=("exposure",), presets=(), seconds=0.3, image_scale=0.0625,
                           scale=0.1, modes=("warp",), speed_seconds=0.0, pictures=tmp_path,
                           command="nuav2 bench ablation (test)")
    result = bench_ablation(opts)
    assert set(result["rows"]) == {"easy", "+exposure"}
    easy, exposed = result["rows"]["easy"]["warp"], result["rows"]["+exposure"]["warp"]
    assert easy["psnr_db_whole"] > 15.0 and easy["ssim_ground"] > 0.5
    # The log's images carry exposure, white balance, vignetting and noise; the truth does not.
    assert exposed["delta"]["psnr_db_whole"] < -0.5
    change = exposed["delta"]["psnr_db_whole"]
    assert exposed["psnr_db_whole"] == pytest.approx(easy["psnr_db_whole"] + change, abs=2e-3)
    per_seed = result["per_seed"]["+exposure"][0]
    # scored against the truth at the log's recorded mean exposure too; easy has none, so it is the raw PSNR
    assert len(per_seed["modes"]["warp"]["reference_log_gain"]) == 3
    assert exposed["psnr_ref_db_whole"] != exposed["psnr_db_whole"]
    assert easy["psnr_ref_db_whole"] == easy["psnr_db_whole"]
    assert per_seed["modes"]["warp"]["convert"]["cpu_s"] > 0 and per_seed["frames"] == 3
    assert "synth_speed" not in result  # --speed-seconds 0
    md = markdown_table(result)
    assert "| +exposure |" in md and "nuav2 bench ablation (test)" in md and "Load (1 min)" in md
    picture = cv2.imread(str(tmp_path / "realism_easy.png"))
    assert picture is not None and picture.shape[1] > 2 * picture.shape[0]  # source | truth | warp


def test_cli_rejects_unknown_factor_and_renders_a_saved_result(tmp_path, capsys):
    assert cli_main(["bench", "ablation", "--factors", "fog"]) == 2
    assert "fog" in capsys.readouterr().err
    saved = {"options": {"modes": ["warp"]}, "command": "nuav2 bench ablation", "how": "test",
             "machine_start": {"load_1_5_15": [1.0, 1.0, 1.0], "cpu_count": 2},
             "machine_end": {"load_1_5_15": [2.0, 1.0, 1.0]},
             "rows": {"easy": {"warp": {"psnr_db_whole": 25.0, "psnr_db_ground": 30.0, "ssim_whole": 0.9,
                                        "ssim_ground": 0.95, "paint_px": 0.8, "convert_wall_s": 3.0,
                                        "convert_cpu_s": 1.0}}},
             "synth_speed": {"hard": {"wall_s_per_frame": 1.5, "cpu_s_per_frame": 0.7,
                                      "load_1min": [3.0, 4.5]}}}
    (tmp_path / "r.json").write_text(json.dumps(saved))
    assert cli_main(["bench", "ablation", "--from-json", str(tmp_path / "r.json"), "--markdown",
                     str(tmp_path / "t.md"), "--json"]) == 0
    md = (tmp_path / "t.md").read_text()
    assert "| easy | 25.00 | – | – | 30.00 | 0.900 | 0.950 | 0.80 | 3 (1) |" in md  # no gauge or ref. PSNR
    assert "| hard | 1.50 | 0.70 | 3.0-4.5 |" in md


def test_cli_factors_empty_runs_the_easy_row_and_the_presets_only(tmp_path, capsys):
    args = ["bench", "ablation", "--seeds", "0", "--factors", "", "--presets", "", "--seconds", "0.3",
            "--image-scale", "0.0625", "--scale", "0.08", "--modes", "warp", "--speed-seconds", "0", "--json"]
    assert cli_main(args) == 0
    result = json.loads(capsys.readouterr().out)
    assert list(result["rows"]) == ["easy"]
