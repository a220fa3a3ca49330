"""ordered_thread_map: input order, bounded work in flight, errors surface in the caller."""

import threading
import time

import pytest

from nuav2.threads import ordered_thread_map


def test_results_come_back_in_input_order_with_bounded_work_in_flight():
    lock = threading.Lock()
    state = {"running": 0, "peak": 0}

    def work(i: int) -> int:
        with lock:
            state["running"] += 1
            state["peak"] = max(state["peak"], state["running"])
        time.sleep(0.002 * ((7 * i) % 5))  # later items often finish first
        with lock:
            state["running"] -= 1
        return i * i

    consumed = []
    for r in ordered_thread_map(work, range(40), workers=3, window=4):
        consumed.append(r)
    assert consumed == [i * i for i in range(40)]
    assert 1 < state["peak"] <= 3


def test_one_worker_runs_in_the_calling_thread():
    caller = threading.get_ident()
    assert list(ordered_thread_map(lambda _: threading.get_ident(), range(3), workers=1)) == [caller] * 3


def test_a_failing_item_raises_in_the_consumer():
    def work(i: int) -> int:
        if i == 5:
            raise ValueError("item 5 is bad")
        return i

    got = []
    with pytest.raises(ValueError, match="item 5"):
        for r in ordered_thread_map(work, range(20), workers=2):
            got.append(r)
    assert got == [0, 1, 2, 3, 4]


def test_workers_run_numba_on_the_callers_thread_count():
    """numba keeps its thread count per thread and a new thread starts at every core: without passing the
    caller's count on, a seeding pool inside a 1-thread (or 2-of-64-core) reconstruction would launch
    kernels on every core."""
    import numba

    from nuav2.threads import numba_threads

    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("needs a machine where numba may use 2 threads, to see a limit of 1 apply")
    with numba_threads(1):
        seen = set(ordered_thread_map(lambda _: numba.get_num_threads(), range(6), workers=2))
    assert seen == {1}
    seen = set(ordered_thread_map(lambda _: numba.get_num_threads(), range(6), workers=2))
    assert seen == {numba.get_num_threads()}
