"""``nuav2 bench eval``'s record: what it times and how busy the machine was."""

from __future__ import annotations


def test_eval_benchmark_reports_cpu_time_and_load_next_to_wall_time():
    """Found by review: bench eval reported wall seconds only, and no load."""
    from nuav2.bench.eval import run_eval_benchmark

    out = run_eval_benchmark(n_samples=4, seed=0)
    for key in ("eval_s", "eval_cpu_s", "reference_s", "reference_cpu_s", "speedup", "speedup_cpu"):
        assert out[key] >= 0, key
    assert len(out["load_1min_after_each"]) == 2 and out["machine_at_start"]["cpu_count"] >= 1
    assert out["max_ap_abs_diff"] < 1e-9
