"""The training runs of ``nuav2 bench transfer`` as jobs: one after another, or in parallel workers.

Why parallel: one run with 2 torch threads keeps only about 1.1 of 2 cores busy (small
convolutions, the Python training loop, scipy's Hungarian matching), while two runs with one
thread each keep both busy. A job is everything one run needs, by value (picklable), so a
spawned worker process rebuilds its data from the tensor cache the main process filled first;
each run still lives in its own directory, so resuming works the same either way.
"""

from __future__ import annotations

import logging
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

from nuav2.bench.transfer_config import TransferConfig

log = logging.getLogger(__name__)

_TEST_SETS: dict = {}  # per worker process: output folder -> TestSet (built once per worker)


@dataclass(frozen=True)
class RunJob:
    key: str  # run directory name under runs/, e.g. "truth-s0", "ft5-pretrained-s1"
    set: str  # training set (conversion mode) it reads
    steps: int
    seed: int
    eval_points: int
    fraction: float | None = None  # a scene-level subset of the set (Table 2)
    init: str | None = None  # run key whose model.pt it starts from (fine-tuning)
    tags: tuple[tuple[str, object], ...] = ()  # extra fields of its record: ("set", ...), ("arm", ...)


def train_tensors(cfg: TransferConfig, out: Path, name: str, fraction: float | None = None):
    """A training set's tensors (from ``out/cache`` when there), with the rotation augmentation's GT."""
    from nuav2.bench.transfer_data import train_source
    from nuav2.mapping import load_map_tensors

    root, split = train_source(cfg, out, name)
    return load_map_tensors(
        root,
        cfg.version,
        split,
        cfg.model,
        fraction=fraction,
        seed=cfg.subset_seed,
        cache_dir=out / "cache",
        rotations_deg=tuple(cfg.rotations_deg),
    )


def run_job(cfg: TransferConfig, out: Path, job: RunJob, test=None) -> dict:
    """Train (or reuse) and score one run; ``test``: the TestSet, else built (once per process)."""
    import torch

    from nuav2.bench.transfer import TestSet, run_and_score, train_config

    torch.set_num_threads(cfg.threads)
    if test is None:
        test = _TEST_SETS.get(str(out))
        if test is None:
            test = _TEST_SETS[str(out)] = TestSet(cfg, out)
    data = train_tensors(cfg, out, job.set, job.fraction)
    init = out / "runs" / job.init / "model.pt" if job.init else None
    tcfg = train_config(cfg, job.steps, job.seed, job.eval_points)
    return {**dict(job.tags), **run_and_score(cfg, job.key, out / "runs" / job.key, data, tcfg, test, init)}


def _init_worker(level: int) -> None:
    logging.basicConfig(level=level, format="%(asctime)s %(processName)s %(name)s: %(message)s")


def finished(cfg: TransferConfig, out: Path, job: RunJob) -> bool:
    """Whether the job's run and its evaluations are there for what it would train now (same
    fingerprint): such a job only reads them back, so a rerun spawns no workers for it."""
    import json

    from nuav2.bench.transfer import DECODINGS, train_config
    from nuav2.mapping.train import MODEL, RUN_JSON, run_fingerprint

    run_dir = out / "runs" / job.key
    init = out / "runs" / job.init / "model.pt" if job.init else None
    files = [run_dir / RUN_JSON, run_dir / MODEL] + [run_dir / e for _, e in DECODINGS.values()]
    if (init is not None and not init.is_file()) or not all(f.is_file() for f in files):
        return False
    tcfg = train_config(cfg, job.steps, job.seed, job.eval_points)
    key = run_fingerprint(cfg.model, tcfg, train_tensors(cfg, out, job.set, job.fraction), init)
    records = [json.loads((run_dir / RUN_JSON).read_text()).get("fingerprint")]
    records += [json.loads((run_dir / e).read_text()).get("run_fingerprint") for _, e in DECODINGS.values()]
    return all(r == key for r in records)


def run_jobs(cfg: TransferConfig, out: Path, jobs: list[RunJob], test) -> dict[str, dict]:
    """Every job's record by key. Finished jobs (and everything when ``cfg.workers`` is 1) run in this
    process; the rest in that many spawned workers (spawn, not fork: a forked child of a process that
    has run OpenMP can hang). A job whose ``init`` is another job of the list starts when that one
    has finished (and counts as finished only if that one does); the others start in list order, so
    fine-tuning from scratch overlaps the pretraining runs."""
    keys = {j.key for j in jobs}
    ready: set[str] = set()
    for j in sorted(jobs, key=lambda j: j.init in keys):  # dependents after what they start from
        if (j.init not in keys or j.init in ready) and finished(cfg, out, j):
            ready.add(j.key)
    todo = [j for j in jobs if j.key not in ready]
    done = {j.key: run_job(cfg, out, j, test) for j in jobs if j.key in ready}
    if cfg.workers <= 1 or len(todo) <= 1:
        for j in sorted(todo, key=lambda j: j.init in keys):
            done[j.key] = run_job(cfg, out, j, test)
        return {j.key: done[j.key] for j in jobs}
    import multiprocessing
    from concurrent.futures import FIRST_COMPLETED, wait

    level = logging.getLogger().getEffectiveLevel()
    with ProcessPoolExecutor(
        max_workers=min(cfg.workers, len(todo)),
        mp_context=multiprocessing.get_context("spawn"),
        initializer=_init_worker,
        initargs=(level,),
    ) as pool:
        futures = {}
        waiting = [j for j in todo if j.init in keys and j.init not in ready]
        for j in todo:
            if j not in waiting:
                futures[j.key] = pool.submit(run_job, cfg, out, j)
        while waiting:
            deps = [futures[j.init] for j in waiting if j.init in futures]
            if not deps:
                raise ValueError(f"jobs {[j.key for j in waiting]} wait on each other")
            wait(deps, return_when=FIRST_COMPLETED)
            for j in [j for j in waiting if j.init in futures and futures[j.init].done()]:
                futures[j.init].result()  # a failed dependency fails here
                futures[j.key] = pool.submit(run_job, cfg, out, j)
                waiting.remove(j)
        done.update({key: f.result() for key, f in futures.items()})
    return {j.key: done[j.key] for j in jobs}
