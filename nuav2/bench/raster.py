"""Rasterizer benchmark: CPU kernels on a synthetic street, against the dense torch reference.

Per (image size, Gaussian count): forward and forward+backward wall time (median and min
over repeats, after a warm-up call that also absorbs numba compilation), the peak resident
memory added by one forward+backward, and the speed-up over the dense reference measured in
the same process on a centred crop small enough for the dense N*H*W tensors to fit.
"""

from __future__ import annotations

import ctypes
import gc
import os
import platform
import threading
import time
from collections.abc import Callable, Iterable

import numba
import numpy as np
import torch

import nuav2.splat
from nuav2.bench.street_scene import StreetScene, make_street_scene
from nuav2.splat import rasterize
from nuav2.splat.dense_reference import rasterize_dense

FULL_SIZES = ((240, 135), (480, 270), (960, 540))
FULL_COUNTS = (10_000, 100_000, 300_000)
QUICK_CASES = ((240, 135, 10_000), (480, 270, 100_000))
DENSE_BUDGET = 12_000_000        # visible Gaussians x crop pixels the dense reference may materialise
DENSE_MIN_CROP = 8
NEAR_M = 0.1


def _rss_bytes() -> int:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def _trim_heap() -> None:
    """Give freed heap pages back so the next RSS baseline is honest (glibc only)."""
    gc.collect()
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass


class _PeakRss:
    """Samples RSS every millisecond in a thread (the kernels release the GIL)."""

    def __enter__(self):
        self.base = _rss_bytes()
        self.peak = self.base
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()
        return self

    def _run(self):
        while not self._stop.is_set():
            self.peak = max(self.peak, _rss_bytes())
            time.sleep(0.001)

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()
        self.peak = max(self.peak, _rss_bytes())

    @property
    def delta_mb(self) -> float:
        return (self.peak - self.base) / 2**20


def _loss_weights(h: int, w: int, seed: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return torch.rand(h, w, 3, generator=g), torch.rand(h, w, generator=g), torch.rand(h, w, generator=g)


def _step(fn: Callable, scene: StreetScene, K: np.ndarray, w: int, h: int, weights, backward: bool) -> int:
    """One render (+ backward of a weighted photometric/alpha/depth loss); returns visible count."""
    params = scene.tensors(requires_grad=backward)
    out = fn(*params, scene.world_T_cam, K, w, h, near=NEAR_M)
    if backward:
        wr, wa, wd = weights
        loss = (out.rgb * wr).sum() + (out.alpha * wa).sum() + 0.01 * (out.depth * wd).sum()
        loss.backward()
        bad = [p for p in params if p.grad is None or not torch.isfinite(p.grad).all()]
        if bad:
            raise FloatingPointError("non-finite gradient in the benchmark scene")
    return int(out.meta["visible"].sum())


def _time(fn: Callable, repeats: int) -> list[float]:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return times


def _crop_camera(K: np.ndarray, w: int, h: int, cw: int, ch: int) -> np.ndarray:
    """Intrinsics of the centred cw x ch window of a w x h image."""
    Kc = K.copy()
    Kc[0, 2] -= (w - cw) // 2
    Kc[1, 2] -= (h - ch) // 2
    return Kc


def _dense_comparison(scene: StreetScene, repeats: int) -> dict:
    """Kernel vs dense reference on the largest centred square crop within DENSE_BUDGET."""
    w, h = scene.width, scene.height
    side = min(w, h)
    while side >= DENSE_MIN_CROP:
        Kc = _crop_camera(scene.K, w, h, side, side)
        with torch.no_grad():
            visible = int(rasterize(*scene.tensors(), scene.world_T_cam, Kc, side, side,
                                    near=NEAR_M).meta["visible"].sum())
        if visible * side * side <= DENSE_BUDGET:
            break
        side //= 2
    else:
        return {"skipped": f"even a {DENSE_MIN_CROP}x{DENSE_MIN_CROP} crop needs more than "
                           f"{DENSE_BUDGET:,} dense Gaussian-pixel pairs"}
    weights = _loss_weights(side, side, 1)
    dense = _time(lambda: _step(rasterize_dense, scene, Kc, side, side, weights, True), repeats)
    kernel = _time(lambda: _step(rasterize, scene, Kc, side, side, weights, True), repeats)
    return {"crop_w": side, "crop_h": side, "visible_in_crop": visible,
            "dense_fwdbwd_s": float(np.median(dense)), "kernel_fwdbwd_s": float(np.median(kernel)),
            "speedup_vs_dense": float(np.median(dense) / np.median(kernel))}


def bench_case(w: int, h: int, n: int, repeats: int = 3, seed: int = 0, dense: bool = True) -> dict:
    """Time one (size, count) case; see the module docstring for what is measured."""
    scene = make_street_scene(n, w, h, seed)
    weights = _loss_weights(h, w, seed)
    visible = _step(rasterize, scene, scene.K, w, h, weights, True)          # warm-up (and JIT)
    fwd = _time(lambda: _step(rasterize, scene, scene.K, w, h, weights, False), repeats)
    fwdbwd = _time(lambda: _step(rasterize, scene, scene.K, w, h, weights, True), repeats)
    _trim_heap()
    with _PeakRss() as mem:
        _step(rasterize, scene, scene.K, w, h, weights, True)
    case = {"w": w, "h": h, "n": n, "visible": visible,
            "fwd_s": float(np.median(fwd)), "fwd_s_min": float(min(fwd)),
            "fwdbwd_s": float(np.median(fwdbwd)), "fwdbwd_s_min": float(min(fwdbwd)),
            "peak_rss_mb": round(mem.delta_mb, 1)}
    if dense:
        cmp = _dense_comparison(scene, max(1, min(repeats, 2)))
        case["dense"] = cmp
        case["speedup_vs_dense"] = cmp.get("speedup_vs_dense")
    return case


def run_raster_bench(cases: Iterable[tuple[int, int, int]], repeats: int = 3, dense: bool = True,
                     progress: bool = True) -> dict:
    """Benchmark every (w, h, n) case; returns the JSON-ready report."""
    from nuav2.progress import progress_bar

    cases = list(cases)
    load_before = os.getloadavg()[0]
    t0 = time.perf_counter()
    warm = make_street_scene(1000, 64, 48)
    _step(rasterize, warm, warm.K, 64, 48, _loss_weights(48, 64, 0), True)   # compile outside the cases
    jit_s = time.perf_counter() - t0
    results = [bench_case(w, h, n, repeats=repeats, dense=dense)
               for w, h, n in progress_bar(cases, desc="bench raster", disable=not progress)]
    return {"bench": "raster", "scene": "synthetic street (ground, facades, cars, trees), forward camera",
            "threads": numba.get_num_threads(), "torch_threads": torch.get_num_threads(),
            "omp_wait_policy": nuav2.splat.OMP_WAIT_POLICY,
            "cpu": platform.processor() or platform.machine(), "cpu_count": os.cpu_count(),
            "load_avg_1m": [round(load_before, 2), round(os.getloadavg()[0], 2)],
            "first_call_s": round(jit_s, 2), "repeats": repeats, "cases": results}


def default_cases(quick: bool) -> list[tuple[int, int, int]]:
    if quick:
        return list(QUICK_CASES)
    return [(w, h, n) for w, h in FULL_SIZES for n in FULL_COUNTS]
