"""``nuav2 bench scale`` on two tiny logs (native mode): every candidate timed, the derived figures
consistent with their parts. The plumbing only; no timing relation is asserted."""

from __future__ import annotations

import json

import pytest

pytest.importorskip("ray", reason="bench scale compares with Ray: pip install 'nuav2[ray]'")


def test_bench_scale_times_every_candidate_and_derives_its_figures(capsys):
    from nuav2.bench.scale import CANDIDATES
    from nuav2.cli import main

    assert main(["bench", "scale", "--logs", "2", "--seconds", "0.3", "--modes", "native", "--repeats", "1",
                 "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["logs"] == 2 and result["interleaved"] and result["ray"]["ray_start_s"] > 0
    c = result["candidates"]
    assert set(c) == {f"native/{e}/{w}" for e, w in CANDIDATES}
    for key, r in c.items():
        assert r["wall_s"] > 0 and r["task_s_mean"] > 0 and r["images_per_log"] > 0, key
        assert r["logs_per_hour"] == pytest.approx(2 / r["wall_s"] * 3600, rel=1e-2), key
    m = result["modes"]["native"]
    for e in ("local", "ray"):
        want = c[f"native/{e}/2"]["logs_per_hour"] / (2 * c[f"native/{e}/1"]["logs_per_hour"])
        assert m[f"{e}_scaling_efficiency"] == pytest.approx(want, abs=2e-3)
    ray1, local1 = c["native/ray/1"], c["native/local/1"]
    around = ((ray1["wall_s"] - result["ray"]["ray_start_s"] - 2 * ray1["task_s_mean"])
              - (local1["wall_s"] - 2 * local1["task_s_mean"]))
    assert m["ray_overhead_per_log_s"] == pytest.approx(around / 2, abs=5e-3)
