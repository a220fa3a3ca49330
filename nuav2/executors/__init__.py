"""Where the logs of a conversion run: local processes (the default) or Ray tasks on a cluster.

Both run :func:`nuav2.executors.task.run_one` per log, which writes the log's shard into OUT
atomically; the driver (``nuav2.convert``) then merges the shards, so the tables are the same
bytes whichever executor ran. ``ray`` is imported only when ``executor="ray"``.
"""

from __future__ import annotations

from pathlib import Path

from nuav2.executors.progress import BatchProgress

EXECUTORS = ("local", "ray")


def run_logs(jobs: list[Path], dataroot: Path, options) -> list[dict]:
    """Convert each of ``jobs`` with ``options.executor``; one result dict per log, sorted by log id."""
    from nuav2.executors.task import fault_from_env

    fault = fault_from_env()
    progress = BatchProgress(len(jobs), enabled=options.show_progress)
    try:
        if options.executor == "ray":
            from nuav2.executors.ray_tasks import run_ray

            results = run_ray(jobs, dataroot, options, progress, fault)
        else:
            from nuav2.executors.local import run_local

            results = run_local(jobs, dataroot, options, progress, fault)
    finally:
        progress.close()
    return sorted(results, key=lambda r: r["log_id"])
