"""Ray executor: one Ray task per log on a local or an existing cluster; the driver merges.

Each task runs :func:`nuav2.executors.task.run_one`, so it writes its shard into OUT exactly as
a local process does (atomic rename, same fingerprint); a rerun resumes from complete shards.
A task whose worker process or node dies is retried by Ray (``max_retries``); a log that fails
on its own input returns its error (never raised), so it is reported once and not retried.

OUT must be the same directory on every node: the driver writes a marker file there and a probe
task on every node (and then every conversion task) must read it back, else the run stops with
an error naming the node. ``ray`` is imported only here, and only when this executor is chosen.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import signal
import socket
import tempfile
import threading
import uuid
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

from nuav2.executors.progress import BatchProgress
from nuav2.executors.task import failure, run_one, worker_name

log = logging.getLogger(__name__)

RAY_MISSING = "--executor ray needs the ray package (pip install 'nuav2[ray]')"
MARKER_PREFIX = ".nuav2-visible-"
LOCAL_OBJECT_STORE_BYTES = 256 * 2**20  # tasks return small dicts; the shards go to OUT, not the store
# Per task when not given: render trains with 2 threads. Memory: the peak RSS measured at 1/8 scale
# (0.3 / 0.7 / 0.8 GB, `nuav2 bench scale` and docs/cluster.md) with room for full-size AV2 logs.
DEFAULT_CPUS = {"native": 1.0, "warp": 1.0, "render": 2.0}
DEFAULT_MEMORY_GB = {"native": 2.0, "warp": 4.0, "render": 8.0}
# A custom resource of a local instance: ``--workers`` of it, one per task, so rounding fractional
# ``--cpus-per-task`` up to whole CPUs (``whole_cpus``) never lets more logs run than ``--workers``.
LOG_SLOT = "nuav2_log_slot"
CANCEL_GRACE_S = 10.0  # how long an interrupted driver waits for cancelled tasks to clean up


class RayMissingError(ImportError):
    """``--executor ray`` where the ray package is not installed."""


class RayStartError(ConnectionError):
    """A local Ray instance (no ``--ray-address``) did not start."""


def local_start_failure(e: BaseException) -> str:
    """One line for a local Ray start that failed: Ray's own first line and where its logs are."""
    first = (str(e).strip().splitlines() or [type(e).__name__])[0]
    logs = Path(os.environ.get("RAY_TMPDIR") or tempfile.gettempdir()) / "ray" / "session_latest" / "logs"
    return (f"--executor ray: a local Ray instance did not start ({first}); Ray's logs: {logs}; "
            "or pass --ray-address of a running cluster")


def ray_available() -> bool:
    try:
        import_ray()
    except RayMissingError:
        return False
    return True


def import_ray():
    try:
        import ray
    except ImportError as e:
        raise RayMissingError(RAY_MISSING) from e
    return ray


@contextlib.contextmanager
def connected(address: str | None = None, num_cpus: float | None = None,
              log_slots: int | None = None) -> Iterator:
    """Ray, connected: the running session if there is one (left running), the cluster at ``address``
    (or ``RAY_ADDRESS``), else a local instance with ``num_cpus`` CPUs and ``log_slots`` of
    :data:`LOG_SLOT`, no dashboard (shut down after)."""
    ray = import_ray()
    if ray.is_initialized():
        yield ray
        return
    with _keeping_sigterm_handler():
        _init(ray, address, num_cpus, log_slots)
    try:
        yield ray
    finally:
        ray.shutdown()


@contextlib.contextmanager
def _keeping_sigterm_handler() -> Iterator[None]:
    """Ray's ``init`` installs its own SIGTERM handler in the driver (it logs and exits 1 at once);
    put the caller's back, so the CLI's SIGTERM still cancels the tasks and cleans up."""
    main_thread = threading.current_thread() is threading.main_thread()
    previous = signal.getsignal(signal.SIGTERM) if main_thread else None
    try:
        yield
    finally:
        if callable(previous):  # a Python handler (the CLI's); a default stays Ray's
            signal.signal(signal.SIGTERM, previous)


def _init(ray, address: str | None, num_cpus: float | None, log_slots: int | None) -> None:
    address = address or os.environ.get("RAY_ADDRESS") or None
    if address:
        check_reachable(address)
        use_token_if_present()
        try:
            ray.init(address=address, log_to_driver=False, logging_level=logging.WARNING)
        except (ConnectionError, RuntimeError, ValueError) as e:
            raise ConnectionError(f"Ray cluster {address!r}: {(str(e).splitlines() or [''])[0]}") from e
    else:
        # "local": a new instance, even where `ray start` left a cluster (or its address file) behind
        try:
            ray.init(address="local", num_cpus=whole_cpus(num_cpus), include_dashboard=False,
                     resources={LOG_SLOT: log_slots} if log_slots else None,
                     log_to_driver=False, object_store_memory=LOCAL_OBJECT_STORE_BYTES,
                     logging_level=logging.WARNING)
        except Exception as e:  # Ray raises a bare Exception when its raylet or GCS does not come up
            raise RayStartError(local_start_failure(e)) from e


def whole_cpus(num_cpus: float | None) -> int | None:
    """The CPUs of a local Ray instance as an int (fractions rounded up). Ray 2.60 passes
    ``min(cores, num_cpus)`` to its raylet as ``--maximum_startup_concurrency``, an integer flag:
    ``8.0`` on a machine with more than 8 cores makes the raylet exit before it logs anything, and
    ``ray.init`` then fails with "The current node timed out during startup" (seen on a 16-core GPU
    machine with ``--workers 2 --cpus-per-task 4``; on 2 cores ``min`` picks the int core count)."""
    return None if num_cpus is None else max(1, math.ceil(num_cpus))


def use_token_if_present() -> None:
    """Send this machine's Ray token when connecting by HOST:PORT, as Ray 2.60 does only for
    ``address="auto"``: ``ray start --head`` enables token authentication by default, and a cluster
    without it accepts a client that sends one. An explicit ``RAY_AUTH_MODE`` is respected."""
    try:
        from ray._private.authentication.authentication_token_setup import (
            maybe_enable_token_auth_if_token_available,
        )
    except ImportError:  # another Ray version: RAY_AUTH_MODE / RAY_AUTH_TOKEN as Ray documents them
        return
    maybe_enable_token_auth_if_token_available(warn_if_disabled=False)


def check_reachable(address: str, timeout_s: float = 10.0) -> None:
    """Fail fast with one line when a HOST:PORT (or ray://HOST:PORT) address does not answer;
    ``ray.init`` itself retries for minutes. Other forms (``auto``) are left to Ray."""
    host, _, port = address.removeprefix("ray://").rpartition(":")
    if not host or not port.isdigit():
        return
    try:
        socket.create_connection((host, int(port)), timeout=timeout_s).close()
    except OSError as e:
        raise ConnectionError(f"Ray cluster {address!r} does not answer ({type(e).__name__}); "
                              f"is `ray start --head` running there?") from e


def marker_path(dataroot: Path, token: str) -> Path:
    from nuav2.nuscenes_db.shards import SHARDS_DIRNAME

    return Path(dataroot) / SHARDS_DIRNAME / f"{MARKER_PREFIX}{token}"


def storage_problem(dataroot: str | Path, token: str) -> str | None:
    """None when this node sees the driver's marker in OUT, else why not (runs on the node)."""
    path = marker_path(Path(dataroot), token)
    try:
        seen = path.read_text()
    except OSError as e:
        return f"cannot read {path} ({type(e).__name__})"
    return None if seen == token else f"{path} holds another run's marker"


def probe_node(dataroot: str, token: str) -> dict:
    """Ray task pinned to one node: which nuav2 runs there, and does it see OUT?"""
    import nuav2

    return {"host": socket.gethostname(), "problem": storage_problem(dataroot, token),
            "nuav2": nuav2.__version__}


def convert_log_task(log_dir: str, dataroot: str, options, token: str, fault: str | None) -> dict:
    """Ray task: check OUT is visible here, then convert one log as a local worker would."""
    import ray

    problem = storage_problem(dataroot, token)
    if problem is not None:
        where = f"node {ray.util.get_node_ip_address()} ({socket.gethostname()})"
        return {"log_id": Path(log_dir).name, "log_dir": log_dir, "error": None,
                "storage_problem": f"{where}: {problem}"}
    gpu_ids = ray.get_gpu_ids()
    if options.mode == "render":
        from nuav2.splat.device import DeviceUnavailable

        try:
            options = replace(options, device=task_device(options.device, gpu_ids))
        except DeviceUnavailable as e:
            result = failure(log_dir, f"DeviceUnavailable: {e}", options.mode, worker_name())
            result["summary"].update(node=ray.util.get_node_ip_address(), gpus=[str(g) for g in gpu_ids])
            return result
    result = run_one(log_dir, dataroot, options, fault)
    result["summary"]["node"] = ray.util.get_node_ip_address()
    result["summary"]["gpus"] = [str(g) for g in gpu_ids]
    return result


def task_device(requested: str, gpu_ids: list, visible: str | None = None) -> str:
    """The device a render task reconstructs on: the GPU Ray gave it, else the CPU.

    Ray points CUDA_VISIBLE_DEVICES at the task's GPUs, so the first given GPU is ``cuda:<its
    position there>`` (cuda:0); where Ray leaves the variable alone it is ``cuda:<id>``. A task given no
    GPU never touches one (Ray does not hide the node's GPUs from it). ``auto`` falls back to the CPU
    where gsplat is unusable; ``cuda`` then raises :class:`DeviceUnavailable` naming ``--device``."""
    from nuav2.splat.device import DeviceUnavailable, resolve_device

    if requested == "cpu" or (requested == "auto" and not gpu_ids):
        return "cpu"
    if not gpu_ids:
        raise DeviceUnavailable(f"--device {requested}: this Ray task was given no GPU (--gpus-per-task 0, "
                                f"or a cluster without GPUs)")
    if requested == "auto" and resolve_device("auto").type != "cuda":
        log.warning("render task given GPU %s but CUDA/gsplat is unusable here: training on the CPU", gpu_ids)
        return "cpu"
    first = str(gpu_ids[0])
    visible = os.environ.get("CUDA_VISIBLE_DEVICES") if visible is None else visible
    listed = [x.strip() for x in visible.split(",")] if visible else []
    device = f"cuda:{listed.index(first) if first in listed else int(first)}"
    resolve_device(device, knob="--device")  # CUDA and gsplat usable, the index seen here
    return device


def check_shared_storage(ray, dataroot: Path, token: str) -> None:
    """Run :func:`probe_node` on every alive node; raise ConvertError naming each node that cannot see OUT."""
    from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

    import nuav2
    from nuav2.convert import ConvertError

    nodes = [n for n in ray.nodes() if n.get("Alive")]
    probe = ray.remote(probe_node)
    refs = {probe.options(num_cpus=0,
                          scheduling_strategy=NodeAffinitySchedulingStrategy(n["NodeID"], soft=False))
            .remote(str(dataroot), token): n for n in nodes}
    bad, broken = [], []
    for ref, node in refs.items():
        where = f"node {node.get('NodeManagerAddress')}"
        try:
            seen = ray.get(ref)
        except ray.exceptions.RayTaskError as e:  # e.g. this nuav2 is not installed there
            lines = [line.strip() for line in str(e.cause).splitlines() if line.strip()]
            broken.append(f"{where}: {lines[-1] if lines else type(e.cause).__name__}")
            continue
        if seen["nuav2"] != nuav2.__version__:
            broken.append(f"{where} ({seen['host']}): nuav2 {seen['nuav2']} (driver: {nuav2.__version__})")
        elif seen["problem"] is not None:
            bad.append(f"{where} ({seen['host']}): {seen['problem']}")
    if broken:
        raise ConvertError("a Ray node cannot run nuav2's tasks; every node needs the same nuav2 (and Python "
                           "environment) as the driver: " + "; ".join(broken))
    if bad:
        raise ConvertError(f"OUT {dataroot} is not visible on every Ray node; it must be a shared directory "
                           f"mounted at the same path everywhere: " + "; ".join(bad))


def task_cpus(options) -> float:
    """CPUs of one log's Ray task: ``--cpus-per-task``, else the mode's default."""
    return options.cpus_per_task if options.cpus_per_task is not None else DEFAULT_CPUS[options.mode]


def task_resources(cluster: dict[str, float], options) -> dict:
    """Ray resources of one conversion task: CPUs and memory (options or per-mode defaults), and in
    render mode one GPU when the cluster has GPUs and ``--device`` is not ``cpu`` (``gpus_per_task``
    overrides, 0 forces CPU), and one :data:`LOG_SLOT` where the cluster has them (a local instance).
    ``--device cuda`` where no task can get a GPU is a ConvertError."""
    from nuav2.convert import ConvertError

    cpus = task_cpus(options)
    mem_gb = (options.memory_per_task_gb if options.memory_per_task_gb is not None
              else DEFAULT_MEMORY_GB[options.mode])
    device = options.device if options.mode == "render" else "cpu"
    gpus = options.gpus_per_task
    if gpus is None:
        gpus = 1.0 if device != "cpu" and cluster.get("GPU", 0) >= 1 else 0.0
    if device == "cuda" and not 0 < gpus <= cluster.get("GPU", 0):
        raise ConvertError(f"--device cuda: render tasks need a GPU each, but the Ray cluster has "
                           f"{cluster.get('GPU', 0):g} GPU(s) and --gpus-per-task is {gpus:g}")
    res = {"num_cpus": float(cpus), "num_gpus": float(gpus)}
    if mem_gb > 0:
        res["memory"] = int(mem_gb * 2**30)
    if cluster.get(LOG_SLOT, 0) >= 1:
        res["resources"] = {LOG_SLOT: 1.0}
    return res


def slots(cluster: dict[str, float], res: dict) -> int:
    """How many tasks with ``res`` the cluster can run at once."""
    fits = [cluster.get("CPU", 0) / res["num_cpus"]] if res["num_cpus"] > 0 else []
    if res["num_gpus"] > 0:
        fits.append(cluster.get("GPU", 0) / res["num_gpus"])
    if res.get("memory"):
        fits.append(cluster.get("memory", 0) / res["memory"])
    fits += [cluster.get(name, 0) / need for name, need in res.get("resources", {}).items()]
    return max(0, math.floor(min(fits))) if fits else 1


def run_ray(jobs: list[Path], dataroot: Path, options, progress: BatchProgress,
            fault: str | None = None) -> list[dict]:
    """Convert ``jobs`` as Ray tasks; returns one result per log (same shape as the local executor)."""
    from nuav2.convert import ConvertError

    if not jobs:
        return []
    local_cpus = options.workers * task_cpus(options)
    try:
        with connected(options.ray_address, num_cpus=local_cpus, log_slots=options.workers) as ray:
            return _run_connected(ray, jobs, Path(dataroot).resolve(), options, progress, fault)
    except RayStartError as e:
        raise ConvertError(str(e)) from e
    except ConnectionError as e:
        raise ConvertError(f"--ray-address: {e}") from e


def _run_connected(ray, jobs: list[Path], root: Path, options, progress: BatchProgress,
                   fault: str | None) -> list[dict]:
    from nuav2.atomic import atomic_write_bytes
    from nuav2.convert import ConvertError

    token = uuid.uuid4().hex
    marker = marker_path(root, token)
    # A driver killed with SIGKILL left its marker; convert holds OUT's lock, so any other one is stale.
    for stale in marker.parent.glob(f"{MARKER_PREFIX}*"):
        with contextlib.suppress(OSError):
            stale.unlink()
    atomic_write_bytes(marker, token.encode())
    try:
        check_shared_storage(ray, root, token)
        cluster = ray.cluster_resources()
        res = task_resources(cluster, options)
        n_slots = slots(cluster, res)
        if n_slots < 1:
            raise ConvertError(f"no Ray node can hold one task ({res}); the cluster has {cluster}; "
                               f"lower --cpus-per-task / --memory-per-task / --gpus-per-task")
        log.info("ray: %d logs, %s per task, %d at once", len(jobs), res, n_slots)
        task = ray.remote(convert_log_task).options(max_retries=options.max_retries,
                                                    retry_exceptions=False, **res)
        quiet = replace(options, show_progress=False)
        pending = {task.remote(str(d), str(root), quiet, token, fault): d for d in jobs}
        try:
            return _collect(ray, pending, root, options, progress, n_slots)
        except BaseException:  # Ctrl-C / SIGTERM: let running logs remove their files before Ray stops
            cancel_and_wait(ray, list(pending))
            raise
    finally:
        with contextlib.suppress(OSError):
            marker.unlink()


def cancel_and_wait(ray, refs: list, grace_s: float = CANCEL_GRACE_S) -> None:
    """Cancel ``refs``: queued tasks are dropped, running ones get a KeyboardInterrupt, which unwinds
    their log's cleanup (its written files are removed); wait up to ``grace_s`` for them to end."""
    for ref in refs:
        with contextlib.suppress(Exception):
            ray.cancel(ref, force=False)
    with contextlib.suppress(Exception):
        ray.wait(refs, num_returns=len(refs), timeout=grace_s)


def _collect(ray, pending: dict, dataroot: Path, options, progress: BatchProgress,
             n_slots: int) -> list[dict]:
    from nuav2.convert import ConvertError

    results = []
    while pending:
        progress.update(running=min(len(pending), n_slots))
        ready, _ = ray.wait(list(pending), num_returns=1, timeout=progress.line_every_s)
        for ref in ready:
            log_dir = pending.pop(ref)
            try:
                r = ray.get(ref)
            except ray.exceptions.RayTaskError as e:  # the task raised (run_one returns input errors)
                r = failure(log_dir, f"Ray task raised {type(e.cause).__name__}: {e.cause}", options.mode)
            except ray.exceptions.RayError as e:  # worker process or node died, past the retries
                first = (str(e).strip().splitlines() or [""])[0]
                r = failure(log_dir, f"Ray task failed after {options.max_retries} retries: "
                                     f"{type(e).__name__}: {first}", options.mode)
            if r.get("storage_problem"):
                for other in pending:
                    ray.cancel(other, force=True)
                raise ConvertError(f"OUT {dataroot} is not visible to every Ray task; it must be a shared "
                                   f"directory mounted at the same path on every node: "
                                   f"{r['storage_problem']}")
            results.append(r)
            progress.update(finished=1, failed=r["error"] is not None)
    return results
