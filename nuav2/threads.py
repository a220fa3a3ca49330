"""Ordered work on a few threads with bounded memory, for per-image loops whose heavy parts (compiled
kernels, OpenCV, BLAS) release the GIL."""

from __future__ import annotations

import contextlib
import sys
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from functools import partial
from itertools import islice
from typing import TypeVar

T = TypeVar("T")
R = TypeVar("R")
_DONE = object()


def ordered_thread_map(fn: Callable[[T], R], items: Iterable[T], workers: int,
                       window: int | None = None) -> Iterator[R]:
    """``map(fn, items)`` on ``workers`` threads: results come back in input order, and at most
    ``window`` (default 2 x workers) are in flight, so a loop over a thousand images never holds a
    thousand results. One worker (or fewer) runs in the calling thread. The workers run numba's
    kernels on the caller's numba thread count (numba keeps it per thread, and a new thread starts
    at every core of the machine)."""
    if workers <= 1:
        yield from map(fn, items)
        return
    window = max(1, window or 2 * workers)
    it = iter(items)
    numba = sys.modules.get("numba")  # only when something has loaded it: no import for plain loops
    initializer = partial(numba.set_num_threads, numba.get_num_threads()) if numba is not None else None
    with ThreadPoolExecutor(max_workers=workers, initializer=initializer) as pool:
        pending = deque(pool.submit(fn, item) for item in islice(it, window))
        try:
            while pending:
                result = pending.popleft().result()
                nxt = next(it, _DONE)
                if nxt is not _DONE:
                    pending.append(pool.submit(fn, nxt))
                yield result
        finally:
            for f in pending:
                f.cancel()


@contextlib.contextmanager
def numba_threads(n: int) -> Iterator[None]:
    """The numba kernels launched from this thread inside the block run on at most ``n`` threads.

    numba's own default is every core of the machine: a log that a worker trains on 2 of a node's 64
    cores would launch 64 threads per kernel, and two workers on a 2-core machine four."""
    import numba

    before = numba.get_num_threads()
    numba.set_num_threads(max(1, min(int(n), numba.config.NUMBA_NUM_THREADS)))
    try:
        yield
    finally:
        numba.set_num_threads(before)
