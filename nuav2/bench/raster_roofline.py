"""The arithmetic floor of Gaussian compositing on this machine, measured, for ``bench raster``.

One Gaussian-pixel contribution needs at least: the conic's quadratic form, one exp, the
alpha clamp, the transmittance update and four multiply-adds (colour and depth). This kernel
does exactly that over a flat array of independent evaluations, with every freedom the real
compositor does not have (fast-math reassociation, no per-pixel bookkeeping, no gathers), so
its rate is an upper bound: time per contribution against it is the fraction of the roofline
reached. Forward and backward each evaluate every contribution at least once, so the
fwd+bwd floor is 2 x contributions / rate.
"""

from __future__ import annotations

import time

import numba
import numpy as np
from numba import njit, prange

from nuav2.splat._fastexp import exp_neg_lanes

_N = 1 << 16              # evaluations per pass (fits in L2 with its inputs)


@njit(parallel=True, fastmath=True, cache=True, nogil=True)
def _evaluate(dx, dy, conic, colour, passes, out):
    n_groups = out.shape[0]
    per = (dx.shape[0] + n_groups - 1) // n_groups
    for p in prange(n_groups):
        r = np.float32(0.0)
        g = np.float32(0.0)
        b = np.float32(0.0)
        d = np.float32(0.0)
        t_sum = np.float32(0.0)
        for _ in range(passes):
            for i in range(p * per, min(dx.shape[0], (p + 1) * per)):
                x = dx[i]
                y = dy[i]
                s = np.float32(0.5) * (conic[0] * x * x + conic[2] * y * y) + conic[1] * x * y
                alpha = min(np.float32(0.999), conic[3] * exp_neg_lanes(s))
                t = np.float32(1.0) - alpha
                w = alpha * t
                r += w * colour[0]
                g += w * colour[1]
                b += w * colour[2]
                d += w * colour[3]
                t_sum += t
        out[p] = r + g + b + d + t_sum


def evaluations_per_second(threads: int, seconds: float = 0.3) -> tuple[float, float]:
    """Rate of the minimal contribution work on ``threads`` numba threads, best of a few runs:
    (per wall second, per CPU second of the process). The second is what one core sustains
    while it runs, so it is much less sensitive to other jobs on the machine."""
    rng = np.random.default_rng(0)
    dx = rng.uniform(-3.0, 3.0, _N).astype(np.float32)
    dy = rng.uniform(-3.0, 3.0, _N).astype(np.float32)
    conic = np.array([0.3, 0.05, 0.4, 0.9], np.float32)
    colour = np.array([0.2, 0.5, 0.7, 12.0], np.float32)
    before = numba.get_num_threads()
    numba.set_num_threads(threads)
    try:
        out = np.zeros(threads, np.float32)
        _evaluate(dx, dy, conic, colour, 1, out)                   # compile / warm
        passes = 8
        while True:
            t0 = time.perf_counter()
            _evaluate(dx, dy, conic, colour, passes, out)
            dt = time.perf_counter() - t0
            if dt > seconds / 5:
                break
            passes *= 2
        best_wall = best_cpu = float("inf")
        for _ in range(5):
            c0, t0 = time.process_time(), time.perf_counter()
            _evaluate(dx, dy, conic, colour, passes, out)
            best_wall = min(best_wall, time.perf_counter() - t0)
            best_cpu = min(best_cpu, time.process_time() - c0)
        return passes * _N / best_wall, passes * _N / max(best_cpu, 1e-9)
    finally:
        numba.set_num_threads(before)
