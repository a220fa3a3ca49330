"""``nuav2 bench convert --json`` on a tiny synthetic log: consistent numbers (timings are not asserted)."""

from __future__ import annotations

import json
import math

from nuav2.cli import main


def test_bench_convert_prints_rates_and_ratio(capsys):
    code = main(["bench", "convert", "--seconds", "0.5", "--image-scale", "0.125", "--repeats", "1",
                 "--json"])
    assert code == 0
    result = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert result["frames"] == 5 + 5 * 2 * 7  # 5 sweeps, 7 ring cameras at twice the lidar rate
    assert result["samples"] == 5
    for key in ("frames_per_s", "av2_read_frames_per_s", "ratio_vs_av2_read", "convert_s", "av2_read_s",
                "convert_cpu_s", "av2_read_cpu_s", "ratio_vs_av2_read_cpu"):
        assert math.isfinite(result[key]) and result[key] > 0, key
    assert math.isclose(result["ratio_vs_av2_read"], result["frames_per_s"] / result["av2_read_frames_per_s"])
    assert math.isclose(result["frames_per_s"], result["frames"] / result["convert_s"])
    # CPU seconds and the load next to the wall seconds (found by review: wall time alone)
    assert math.isclose(result["ratio_vs_av2_read_cpu"], result["av2_read_cpu_s"] / result["convert_cpu_s"])
    assert len(result["load_1min"]) == 2
