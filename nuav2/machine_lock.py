"""One process at a time for a step that must not run concurrently: per machine (a lock file) or per
folder (a lock on the folder itself)."""

from __future__ import annotations

import contextlib
import fcntl
import os
from collections.abc import Iterator
from pathlib import Path


@contextlib.contextmanager
def machine_lock(path: Path) -> Iterator[bool]:
    """Hold an exclusive ``flock`` on ``path`` (created if missing) for the ``with`` block; other
    processes entering with the same path wait. Yields False, unlocked, where the file cannot be
    made (a read-only home): the step then runs as it would without the lock."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    except OSError:
        yield False
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield True
    finally:
        os.close(fd)  # closing releases the lock


@contextlib.contextmanager
def folder_lock(path: Path) -> Iterator[bool]:
    """Hold an exclusive, non-blocking ``flock`` on the folder ``path`` itself (no lock file left in it)
    for the ``with`` block: BlockingIOError at once if another process holds it. Yields False, unlocked,
    where the file system cannot lock a folder (NFS without flock): the work then runs as before."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_DIRECTORY)
    except OSError:
        yield False
        return
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise
        except OSError:
            locked = False
        else:
            locked = True
        yield locked
    finally:
        os.close(fd)  # closing releases the lock
