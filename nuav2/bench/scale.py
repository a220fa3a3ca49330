"""Benchmark: conversion throughput (logs per hour) with local processes and with Ray, at 1 and 2 workers.

Every candidate converts the same synthetic logs into a fresh OUT through ``convert_av2``, as the
CLI does (a Ray candidate starts its own local instance and shuts it down, so Ray's start-up is
in its wall time). Candidates are interleaved: each repeat runs every mode and executor once, and
the fastest repeat counts. Per-task figures come from ``convert_report.json`` (``logs``).

Ray's overhead is given three ways: starting and stopping a local instance (``ray_start_s``), a
no-op task's round trip on a running instance (``noop_task_ms``), and per log
(``ray_overhead_per_log_s``): the wall time Ray at one worker spends around its tasks (its wall
less the start-up and the tasks' own seconds) beyond what one local process spends around its
tasks. Counting around the tasks keeps it fair where a task runs at another speed under Ray (a
warp log renders on two threads in one local process, on one in a 1-CPU Ray task).
Scaling efficiency = logs/hour at 2 workers / (2 x logs/hour at 1 worker).
"""

from __future__ import annotations

import os
import resource
import shutil
import statistics
import tempfile
import time
from pathlib import Path

CANDIDATES = (("local", 1), ("local", 2), ("ray", 1), ("ray", 2))


def _cpu_s() -> float:
    """CPU seconds of this process and of every reaped descendant: local pool workers, Ray's daemons;
    not Ray's worker processes (orphaned when the raylet stops), so compare ``task_cpu_s_mean``."""
    ch = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + ch.ru_utime + ch.ru_stime


def _convert_once(src: Path, out: Path, mode: str, executor: str, workers: int, scale: float) -> dict:
    from nuav2.convert import ConvertOptions, convert_av2

    shutil.rmtree(out, ignore_errors=True)
    options = ConvertOptions(mode=mode, executor=executor, workers=workers, scale=scale, show_progress=False)
    load = os.getloadavg()[0]
    c0, t0 = _cpu_s(), time.perf_counter()
    report = convert_av2(src, out, options)
    wall, cpu = time.perf_counter() - t0, _cpu_s() - c0
    if report.failed:
        raise RuntimeError(f"bench scale: {mode}/{executor}: {report.failed}")
    per_log = list(report.logs.values())
    shutil.rmtree(out, ignore_errors=True)
    # cpu_s: driver + local workers + reaped Ray daemons, not Ray's workers: compare executors by
    # task_cpu_s_mean (each log's own CPU seconds, measured in its worker)
    return {"wall_s": wall, "cpu_s": cpu, "load_1min_before": load, "load_1min_after": os.getloadavg()[0],
            "task_s_mean": statistics.fmean(s["seconds"] for s in per_log),
            "task_cpu_s_mean": statistics.fmean(s["cpu_seconds"] for s in per_log),
            "images_per_log": statistics.fmean(s["images"] for s in per_log),
            "peak_rss_mb_max": max((s["peak_rss_mb"] or 0) for s in per_log)}


def _ray_overheads(noop_tasks: int = 50) -> dict:
    """Start + stop of a local 2-CPU instance, and the round trip of a no-op task on it."""
    from nuav2.executors.ray_tasks import connected

    t0 = time.perf_counter()
    with connected(None, num_cpus=2) as ray:
        started = time.perf_counter() - t0
        noop = ray.remote(num_cpus=1)(_noop)
        ray.get(noop.remote())  # a worker process exists from here on
        t1 = time.perf_counter()
        for _ in range(noop_tasks):
            ray.get(noop.remote())
        noop_ms = (time.perf_counter() - t1) / noop_tasks * 1e3
        t2 = time.perf_counter()
    return {"ray_start_s": round(started, 3), "ray_stop_s": round(time.perf_counter() - t2, 3),
            "noop_task_ms": round(noop_ms, 3)}


def _noop() -> None:
    return None


def bench_scale(logs: int = 4, seconds: float = 2.0, image_scale: float = 0.125, warp_scale: float = 0.125,
                modes: tuple[str, ...] = ("native", "warp"), repeats: int = 2, seed: int = 0,
                workdir: Path | None = None) -> dict:
    """Generate ``logs`` synthetic logs, then time every (mode, executor, workers) candidate, interleaved."""
    from nuav2.executors.ray_tasks import ray_available
    from nuav2.synth import SynthConfig, generate_log

    if not ray_available():
        raise RuntimeError("bench scale compares with Ray: pip install 'nuav2[ray]'")
    tmp = Path(tempfile.mkdtemp(prefix="nuav2-bench-scale-", dir=workdir))
    try:
        config = SynthConfig(seconds=seconds, image_scale=image_scale)
        src = [generate_log(tmp / "av2", seed=seed + i, config=config) for i in range(logs)][0].parent
        for mode in modes:  # compile / load the numba caches once, outside the timings
            _convert_once(src, tmp / "warm", mode, "local", 1, warp_scale)
        runs: dict[str, list[dict]] = {}
        overheads = []
        for rep in range(repeats):
            overheads.append(_ray_overheads())
            k = rep % len(CANDIDATES)
            order = CANDIDATES[k:] + CANDIDATES[:k]  # rotated each repeat: no candidate always goes first
            for mode in modes:
                for executor, workers in order:
                    key = f"{mode}/{executor}/{workers}"
                    runs.setdefault(key, []).append(
                        _convert_once(src, tmp / "out", mode, executor, workers, warp_scale))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    best = {k: min(v, key=lambda r: r["wall_s"]) for k, v in runs.items()}
    ray_oh = {k: min(o[k] for o in overheads) for k in overheads[0]}
    result = {"logs": logs, "seconds_per_log": seconds, "sweeps_per_log": int(round(seconds * 10)),
              "image_scale": image_scale, "warp_scale": warp_scale, "repeats": repeats,
              "cpus": os.cpu_count(), "interleaved": True, "ray": ray_oh, "candidates": {}, "modes": {}}
    for key, r in best.items():
        result["candidates"][key] = {**{k: round(v, 3) for k, v in r.items()},
                                     "logs_per_hour": round(logs / r["wall_s"] * 3600, 1)}
    for mode in modes:
        c = result["candidates"]
        m = {}
        for executor in ("local", "ray"):
            one, two = c[f"{mode}/{executor}/1"], c[f"{mode}/{executor}/2"]
            m[f"{executor}_scaling_efficiency"] = round(two["logs_per_hour"] / (2 * one["logs_per_hour"]), 3)
        ray1, local1 = c[f"{mode}/ray/1"], c[f"{mode}/local/1"]
        around_ray = ray1["wall_s"] - ray_oh["ray_start_s"] - logs * ray1["task_s_mean"]
        around_local = local1["wall_s"] - logs * local1["task_s_mean"]
        m["ray_overhead_per_log_s"] = round((around_ray - around_local) / logs, 3)
        m["task_s_mean_local_1"] = c[f"{mode}/local/1"]["task_s_mean"]
        m["task_cpu_s_mean_local_1"] = c[f"{mode}/local/1"]["task_cpu_s_mean"]
        m["peak_rss_mb_max"] = max(c[f"{mode}/{e}/{w}"]["peak_rss_mb_max"] for e, w in CANDIDATES)
        result["modes"][mode] = m
    return result
