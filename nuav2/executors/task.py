"""One log as one unit of work, the same in a local process and in a Ray task: convert, time, summarise.

The result is the plain dict of :func:`nuav2.convert.convert_one_log` (``log_id``, ``log_dir``,
``error``) plus ``summary`` (seconds, images, mode, worker) for the report. The shard itself is
written by ``convert_one_log``, atomically, so every executor produces the same bytes.

``NUAV2_TEST_FAULT=ACTION:DIR`` is a fault-injection hook for the executor tests, read by the
driver and handed to each task. Every attempt at a log appends the worker's pid to
``DIR/<log_id>.attempts``; then ``kill`` kills the worker (SIGKILL) on the log's first attempt,
after its images are written and before its shard is saved; ``crash`` does so on every attempt;
``hang`` sleeps until the process is killed or interrupted (an interrupt that unwinds the task,
as a log's cleanup needs, writes ``DIR/<log_id>.stopped`` naming it); ``record`` does nothing more.
"""

from __future__ import annotations

import os
import signal
import socket
import sys
import time
from pathlib import Path

FAULT_ENV = "NUAV2_TEST_FAULT"
FAULT_ACTIONS = ("record", "kill", "crash", "hang")


def fault_from_env() -> str | None:
    """The test hook's spec from the driver's environment (None: no fault)."""
    spec = os.environ.get(FAULT_ENV) or None
    if spec is not None and spec.partition(":")[0] not in FAULT_ACTIONS:
        raise ValueError(f"{FAULT_ENV}={spec!r}: expected one of {FAULT_ACTIONS} followed by ':DIR'")
    return spec


def _attempts_file(spec: str, log_id: str) -> Path:
    return Path(spec.partition(":")[2]) / f"{log_id}.attempts"


def record_attempt(spec: str | None, log_id: str) -> None:
    """Test hook, at the start of a log: note this attempt; ``hang`` stops here until killed."""
    if not spec:
        return
    attempts = _attempts_file(spec, log_id)
    with attempts.open("a") as f:
        f.write(f"{os.getpid()}\n")
    try:
        while spec.startswith("hang:"):
            time.sleep(1.0)
    except BaseException as e:  # SystemExit (SIGTERM in a pool worker), KeyboardInterrupt (Ray's cancel)
        attempts.with_suffix(".stopped").write_text(type(e).__name__)
        raise


def inject_fault(spec: str | None, log_id: str) -> None:
    """Test hook, between a log's data files and its shard: ``kill`` (first attempt) / ``crash``."""
    if not spec:
        return
    action = spec.partition(":")[0]
    first = len(_attempts_file(spec, log_id).read_text().split()) == 1
    if action == "crash" or (action == "kill" and first):
        os.kill(os.getpid(), signal.SIGKILL)


def worker_name() -> str:
    return f"{socket.gethostname()}:{os.getpid()}"


def run_one(log_dir: str | Path, dataroot: str | Path, options, fault: str | None = None) -> dict:
    """Convert one log (``options``: a :class:`nuav2.convert.ConvertOptions`) and time it."""
    from nuav2.convert import convert_one_log

    t0, c0 = time.perf_counter(), time.process_time()
    record_attempt(fault, Path(log_dir).name)
    result = convert_one_log(Path(log_dir), Path(dataroot), options,
                             after_write=(lambda log_id: inject_fault(fault, log_id)) if fault else None)
    result["summary"] = {"seconds": round(time.perf_counter() - t0, 3),
                         "cpu_seconds": round(time.process_time() - c0, 3), "images": result.pop("images", 0),
                         "mode": options.mode, "worker": worker_name(), "peak_rss_mb": peak_rss_mb()}
    device = result.pop("device", None)
    if device is not None:  # render mode: where it reconstructed and rendered (cpu, cuda:N)
        result["summary"]["device"] = device
    return result


def peak_rss_mb() -> float | None:
    """This process's peak resident memory so far (what --memory-per-task must cover), None if unknown."""
    try:
        import resource
    except ImportError:
        return None
    kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # kB on Linux, bytes on macOS
    return round(kb / (2**20 if sys.platform == "darwin" else 2**10), 1)


def failure(log_dir: str | Path, error: str, mode: str, worker: str | None = None) -> dict:
    """A result for a log whose task never returned (its worker died past the retries)."""
    return {"log_id": Path(log_dir).name, "log_dir": str(log_dir), "error": error,
            "summary": {"seconds": None, "images": 0, "mode": mode, "worker": worker}}
