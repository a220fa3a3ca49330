"""``nuav2 demo`` end to end in warp mode on a short log: the real writer, validate + devkit, region scores
read back from the written database, the side-by-side PNG and the printed table."""

from __future__ import annotations

import json

from nuav2.demo import DemoOptions, format_summary, run_demo


def test_demo_in_warp_mode_reports_regions_and_paint_per_preset(tmp_path):
    summary = run_demo(DemoOptions(out=tmp_path, mode="warp", scale=0.1, seconds=0.3, presets=("easy",),
                                   progress=False))
    easy = summary["presets"]["easy"]
    assert easy["samples"] == 3 and easy["validation"] == "ok"
    q = easy["quality"]
    assert q["images"] == 3 * 6
    assert 20.0 < q["psnr_db"]["whole"] < 60.0  # the warp measured ~27 dB on the default scene
    assert q["psnr_db"]["ground"] is not None and q["psnr_db"]["sky"] is not None
    assert len(q["per_camera"]) == 6 and all(c["whole"]["images"] == 3 for c in q["per_camera"].values())
    assert q["paint_points_truth"] > 100 and q["paint_median_px"] < q["paint_median_px_truth"] + 1.0
    assert set(easy["timings"]) == {"synth", "convert", "validate", "score"}
    assert (tmp_path / "easy" / "demo_side_by_side.png").stat().st_size > 1000
    on_disk = json.loads((tmp_path / "demo_summary.json").read_text())
    assert on_disk["presets"]["easy"]["quality"]["psnr_db"] == q["psnr_db"]
    text = format_summary(summary)
    assert "PSNR dB / SSIM, ground" in text and "lane paint px (truth)" in text
    assert json.loads(text.splitlines()[-1])["psnr_db_mean"]["easy"] == q["psnr_db"]["whole"]
