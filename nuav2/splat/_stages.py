"""Optional per-stage timing of the CPU rasterizer, for ``nuav2 bench raster``.

The kernels' callers wrap each stage in :func:`stage` and report work counts with
:func:`count`; both cost one global lookup unless a benchmark has opened
:func:`record_stages`, which then sums wall and process CPU time (all threads) per stage
name, and the counts per name, over the calls made inside it.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator

_active: dict[str, list[float]] | None = None


@contextlib.contextmanager
def record_stages() -> Iterator[dict[str, list[float]]]:
    """Collect {stage: [wall_s, cpu_s]} and {counter: [total]} for the rasterizer calls made
    inside the block."""
    global _active
    outer = _active
    _active = {}
    try:
        yield _active
    finally:
        _active = outer


def count(name: str, value: float) -> None:
    """Add ``value`` to the counter ``name`` when a recorder is open."""
    if _active is not None:
        _active.setdefault(name, [0.0])[0] += value


@contextlib.contextmanager
def stage(name: str) -> Iterator[None]:
    """Time the enclosed block under ``name`` when a recorder is open (else do nothing)."""
    rec = _active
    if rec is None:
        yield
        return
    w0, c0 = time.perf_counter(), time.process_time()
    try:
        yield
    finally:
        acc = rec.setdefault(name, [0.0, 0.0])
        acc[0] += time.perf_counter() - w0
        acc[1] += time.process_time() - c0
