"""Local processes, one log each (the default executor).

Workers are spawned processes that exit when the main process dies (finding: a killed
``convert`` left its workers running for minutes, finishing shards nobody would merge). A worker
that dies (OOM killer, a signal) breaks the pool; its logs are retried in a fresh pool, at most
``max_retries`` times, like a Ray task whose worker died.

Interrupts belong to the main process: workers ignore SIGINT (a Ctrl-C reaches the whole process
group, and a worker interrupted while it held the pool's queue lock hung the pool's shutdown for
good); on KeyboardInterrupt (or SIGTERM, which the CLI turns into one) the main process cancels
what has not started and sends its workers SIGTERM, which unwinds their logs' cleanup.
"""

from __future__ import annotations

import contextlib
import ctypes
import multiprocessing
import os
import signal
import sys
import threading
import time
from collections.abc import Iterator
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import replace
from pathlib import Path

from nuav2.executors.progress import BatchProgress
from nuav2.executors.task import failure, run_one

PR_SET_PDEATHSIG = 1  # linux/prctl.h
PARENT_POLL_S = 1.0
EXIT_GRACE_S = 10.0


_STOPPING: list[int] = []  # in a worker: the exit code once SIGTERM told it to stop


def _exit_on_sigterm(signum, frame) -> None:  # noqa: ARG001 - signal handler signature
    # SystemExit unwinds the task, so temp files and .partial directories are removed on the way out;
    # a second SIGTERM (the process group's, then the main process's) must not cut that cleanup short.
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    _STOPPING.append(128 + signum)
    raise SystemExit(128 + signum)


def _worker_task(fn, *args):
    """``fn(*args)`` in a pool worker; once SIGTERM has unwound it, the worker ends. concurrent.futures'
    worker loop catches the SystemExit as the task's error and takes the next queued task: a worker
    whose driver was killed started and finished another log (its shard merged by nobody), with
    SIGTERM ignored from then on, until the parent watch cut it off 10 s later."""
    if _STOPPING:
        os._exit(_STOPPING[0])
    try:
        return fn(*args)
    except SystemExit:
        if _STOPPING:
            os._exit(_STOPPING[0])  # the task's cleanup ran while SystemExit unwound it
        raise


class _StoppablePool(ProcessPoolExecutor):
    """A process pool whose tasks run through :func:`_worker_task`."""

    def submit(self, fn, /, *args, **kwargs):
        if kwargs:
            raise TypeError("worker_pool tasks take positional arguments only")
        return super().submit(_worker_task, fn, *args)


def _watch_parent(parent_pid: int) -> None:
    while True:
        time.sleep(PARENT_POLL_S)
        if os.getppid() != parent_pid:
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(EXIT_GRACE_S)
            os._exit(1)


def exit_with_parent(parent_pid: int) -> None:
    """Worker initializer: end this process when ``parent_pid`` dies.

    On Linux the kernel sends SIGTERM at once (PR_SET_PDEATHSIG); a polling thread covers other
    systems. SIGTERM raises SystemExit so the task's cleanup runs; after a grace period the
    process exits regardless.
    """
    signal.signal(signal.SIGTERM, _exit_on_sigterm)
    if sys.platform.startswith("linux"):
        with contextlib.suppress(OSError, AttributeError):
            ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)
    if os.getppid() != parent_pid:  # the parent died before the line above
        os._exit(1)
    threading.Thread(target=_watch_parent, args=(parent_pid,), daemon=True, name="watch-parent").start()


@contextlib.contextmanager
def worker_pool(workers: int, initializer=None, initargs: tuple = ()) -> Iterator[ProcessPoolExecutor]:
    """A pool of spawned processes that exit with this one (``initializer`` runs after that is set up),
    shut down normally at the end, but on an interrupt (or any error) stopped at once: queued work
    cancelled, workers sent SIGTERM (their cleanup runs), killed after a grace period."""
    pool = _StoppablePool(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                          initializer=_init_worker, initargs=(os.getpid(), initializer, initargs))
    try:
        yield pool
    except BaseException:
        _stop_pool(pool)
        raise
    pool.shutdown(wait=True)


def _init_worker(parent_pid: int, initializer, initargs: tuple) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    exit_with_parent(parent_pid)
    if initializer is not None:
        initializer(*initargs)


def _stop_pool(pool: ProcessPoolExecutor, grace_s: float = EXIT_GRACE_S) -> None:
    processes = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for proc in processes:
        with contextlib.suppress(OSError, ValueError):
            proc.terminate()
    deadline = time.monotonic() + grace_s
    for proc in processes:
        with contextlib.suppress(OSError, ValueError, AssertionError):
            proc.join(max(0.0, deadline - time.monotonic()))
            if proc.is_alive():
                proc.kill()
                proc.join(1.0)
    # The pool's manager thread closes its wake-up pipe once the workers are gone; at exit Python 3.11
    # writes to that pipe unless it is already closed (a race that printed "OSError: Bad file
    # descriptor" after "terminated"), so let the thread finish here.
    manager = getattr(pool, "_executor_manager_thread", None)
    if manager is not None:
        manager.join(max(1.0, deadline - time.monotonic()))


def run_local(jobs: list[Path], dataroot: Path, options, progress: BatchProgress,
              fault: str | None = None) -> list[dict]:
    """Convert ``jobs`` in this process (one worker) or in a pool of ``options.workers`` processes."""
    if options.workers == 1 or len(jobs) <= 1:
        results = []
        inline = replace(options, show_progress=progress.tty)  # per-log bars under the batch bar, on a TTY
        for log_dir in jobs:
            progress.update(running=1)
            r = run_one(log_dir, dataroot, inline, fault)
            results.append(r)
            progress.update(running=0, finished=1, failed=r["error"] is not None)
        return results
    quiet = replace(options, show_progress=False)
    results: list[dict] = []
    todo, attempts = list(jobs), 0
    while todo:
        died = _pool_round(todo, dataroot, quiet, progress, fault, results)
        attempts += 1
        if died and attempts > options.max_retries:
            for log_dir in died:
                results.append(failure(log_dir, f"worker process died {attempts} times (killed, or out of "
                                                f"memory?) while converting this log", options.mode))
                progress.update(finished=1, failed=1)
            break
        todo = died
    return results


def _pool_round(jobs: list[Path], dataroot: Path, options, progress: BatchProgress, fault: str | None,
                results: list[dict]) -> list[Path]:
    """One pool over ``jobs``; returns the logs whose worker died (to retry), appends the others' results."""
    workers = min(options.workers, len(jobs))
    died: list[Path] = []
    with worker_pool(workers) as pool:
        pending = {pool.submit(run_one, d, dataroot, options, fault): d for d in jobs}
        while pending:
            progress.update(running=min(len(pending), workers))
            done, _ = wait(pending, timeout=progress.line_every_s, return_when=FIRST_COMPLETED)
            for fut in done:
                log_dir = pending.pop(fut)
                try:
                    r = fut.result()
                except BrokenProcessPool:
                    died.append(log_dir)
                    continue
                results.append(r)
                progress.update(finished=1, failed=r["error"] is not None)
    return died
