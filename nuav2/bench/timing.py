"""Timing that survives a shared machine: wall and CPU seconds side by side, and the load they ran under.

CPU time (``process_time``, all threads of this process) is what a comparison between candidates
should lean on when other jobs share the cores; wall time is what a user waits. The 1-minute load
average is sampled as the work runs, so a table can say how busy the machine was.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field


def load_1min() -> float:
    """The 1-minute load average (0.0 where the platform has none)."""
    try:
        return float(os.getloadavg()[0])
    except OSError:
        return 0.0


@dataclass
class Stopwatch:
    """Accumulates (wall, cpu) seconds of timed blocks and the load seen at their ends::

        sw = Stopwatch()
        with sw:
            work()
        sw.wall_s[-1], sw.cpu_s[-1]
    """

    wall_s: list[float] = field(default_factory=list)
    cpu_s: list[float] = field(default_factory=list)
    load: list[float] = field(default_factory=list)

    def __enter__(self) -> Stopwatch:
        self._t0, self._c0 = time.perf_counter(), time.process_time()
        return self

    def __exit__(self, *exc) -> None:
        self.wall_s.append(time.perf_counter() - self._t0)
        self.cpu_s.append(time.process_time() - self._c0)
        self.load.append(load_1min())

    def summary(self) -> dict:
        """Mean / median wall and CPU seconds per block, their count and the load range."""
        import numpy as np

        if not self.wall_s:
            return {"n": 0}
        return {"n": len(self.wall_s), "wall_s_mean": round(float(np.mean(self.wall_s)), 4),
                "wall_s_median": round(float(np.median(self.wall_s)), 4),
                "cpu_s_mean": round(float(np.mean(self.cpu_s)), 4),
                "cpu_s_median": round(float(np.median(self.cpu_s)), 4),
                "load_1min": [round(min(self.load), 2), round(max(self.load), 2)]}


def machine() -> dict:
    """What the timings ran on: cores, the threads torch and numba use, and the load now."""
    import numba
    import torch

    return {"cpu_count": os.cpu_count(), "torch_threads": torch.get_num_threads(),
            "numba_threads": numba.get_num_threads(), "load_1_5_15": [round(x, 2) for x in os.getloadavg()]}
