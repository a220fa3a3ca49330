"""The per-machine lock that queues gsplat's CUDA build (render tasks starting together on a node)."""

from __future__ import annotations

import multiprocessing as mp
import time
from pathlib import Path

from nuav2.machine_lock import machine_lock  # the spawned children import only this (no torch)


def _hold(path: str, out: str) -> None:
    with machine_lock(Path(path)) as locked:
        start = time.monotonic()
        time.sleep(0.4)
        Path(out).write_text(f"{locked} {start} {time.monotonic()}")


def test_processes_holding_the_lock_never_overlap(tmp_path):
    lock = tmp_path / "ext" / "build.lock"  # its folder does not exist yet
    ctx = mp.get_context("spawn")
    procs = [ctx.Process(target=_hold, args=(str(lock), str(tmp_path / f"{i}.txt"))) for i in range(3)]
    for p in procs:
        p.start()
    for p in procs:
        p.join(60)
        assert p.exitcode == 0
    spans = sorted(tuple(map(float, (tmp_path / f"{i}.txt").read_text().split()[1:])) for i in range(3))
    assert all((tmp_path / f"{i}.txt").read_text().startswith("True") for i in range(3))
    assert all(a[1] <= b[0] for a, b in zip(spans, spans[1:]))  # one after another


def test_a_lock_that_cannot_be_made_runs_the_step_unlocked(tmp_path):
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    ran = []
    with machine_lock(blocker / "sub" / "build.lock") as locked:
        ran.append(locked)
    assert ran == [False]


def test_the_build_lock_sits_in_torchs_extension_folder(monkeypatch, tmp_path):
    from nuav2.splat.gsplat_backend import gsplat_build_lock_path

    monkeypatch.setenv("TORCH_EXTENSIONS_DIR", str(tmp_path))
    assert gsplat_build_lock_path() == tmp_path / "nuav2-gsplat-build.lock"
    monkeypatch.delenv("TORCH_EXTENSIONS_DIR")
    assert gsplat_build_lock_path() == Path.home() / ".cache" / "torch_extensions" / "nuav2-gsplat-build.lock"
