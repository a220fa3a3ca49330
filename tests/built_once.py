"""Session fixtures built once per test run, not once per pytest-xdist worker.

Each xdist worker is a process with a session of its own, so a database that took 30 s to convert
was converted again by the other worker as soon as tests of both used it (the render-mode one cost
~80 s of a 2-core run twice). The first worker to ask builds it under the run's shared temp folder
while holding a lock; the others wait on the lock and reuse what it built. These fixtures are
read-only to their tests, as session scope already requires within one worker."""

from __future__ import annotations

import fcntl
import os
import pickle
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import pytest

T = TypeVar("T")


def built_once(tmp_path_factory: pytest.TempPathFactory, name: str, build: Callable[[Path], T]) -> T:
    """``build(folder)`` run once per test run for ``name`` (a fresh empty folder); every worker gets
    its (picklable) return value. Without xdist: a plain ``mktemp``."""
    if "PYTEST_XDIST_WORKER" not in os.environ:
        return build(tmp_path_factory.mktemp(name, numbered=False))
    shared = tmp_path_factory.getbasetemp().parent / "built_once"  # the run's folder, above popen-gwN
    shared.mkdir(exist_ok=True)
    value_file = shared / f"{name}.pickle"
    with open(shared / f"{name}.lock", "wb") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        if value_file.exists():
            return pickle.loads(value_file.read_bytes())
        folder = shared / name
        shutil.rmtree(folder, ignore_errors=True)  # left by a worker whose build failed
        folder.mkdir()
        value = build(folder)
        tmp = value_file.with_suffix(".partial")
        tmp.write_bytes(pickle.dumps(value))
        tmp.replace(value_file)
        return value
