"""``nuav2 bench eval`` and ``bench loader`` records: what they time and how busy the machine was."""

from __future__ import annotations

pytest_plugins = ["test_writer_support", "e2e_support"]


def test_eval_benchmark_reports_cpu_time_and_load_next_to_wall_time():
    """Found by review: bench eval reported wall seconds only, and no load."""
    from nuav2.bench.eval import run_eval_benchmark

    out = run_eval_benchmark(n_samples=4, seed=0)
    for key in ("eval_s", "eval_cpu_s", "reference_s", "reference_cpu_s", "speedup", "speedup_cpu"):
        assert out[key] >= 0, key
    assert len(out["load_1min_after_each"]) == 2 and out["machine_at_start"]["cpu_count"] >= 1
    assert out["max_ap_abs_diff"] < 1e-9


def test_loader_benchmark_interleaves_and_reports_cpu_time_and_load(native_synth_db):
    """Found by review: bench loader timed its three candidates in three loops, wall time only."""
    from e2e_helpers import VERSION

    from nuav2.bench.loader import bench_loader

    out = bench_loader(native_synth_db, VERSION, max_samples=3)
    assert set(out["cpu_s"]) == set(out["wall_s"]) == {"bare_read", "gt_only", "full"}
    assert all(v > 0 for v in (*out["cpu_s"].values(), *out["wall_s"].values())), out
    assert len(out["load_1min"]) == 2
