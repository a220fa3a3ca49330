"""Atomic file and directory writes: a reader never sees a half-written file or shard.

Temp files and directories come from :mod:`tempfile`, which creates them private (0600 /
0700). A dataset is shared, so each one gets the mode an ordinary ``open``/``mkdir`` would
give it under the user's umask (0644 / 0755 under umask 022) before it is renamed into place.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path


def current_umask() -> int:
    """The process umask, read without changing it where the OS allows (Linux: /proc/self/status)."""
    with contextlib.suppress(OSError, ValueError):
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    mask = os.umask(0o022)  # elsewhere: set and restore (not thread-safe, but only a fallback)
    os.umask(mask)
    return mask


def file_mode() -> int:
    """Mode of a new regular file under the current umask (0644 under umask 022)."""
    return 0o666 & ~current_umask()


def dir_mode() -> int:
    """Mode of a new directory under the current umask (0755 under umask 022)."""
    return 0o777 & ~current_umask()


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Write ``data`` to a temp file beside ``path``, fsync it, then rename over ``path``."""
    with atomic_file(path) as f:
        f.write(data)


def atomic_write_json(path: str | Path, obj, indent: int | None = None) -> None:
    """Deterministic JSON (sorted keys off: callers order records) written atomically."""
    atomic_write_bytes(path, json.dumps(obj, indent=indent, ensure_ascii=False).encode())


@contextlib.contextmanager
def atomic_directory(final: str | Path) -> Iterator[Path]:
    """Yield a temp directory; on success it is renamed to ``final`` (replacing an old one).

    The old one is first renamed aside under a fresh hidden name, then removed; where it cannot
    be removed (a read-only file in it) it stays under that name with a warning, and never
    blocks a later write (a fixed ``.old`` name did: "Directory not empty" on every rerun)."""
    final = Path(final)
    final.parent.mkdir(parents=True, exist_ok=True)
    tmp = None
    try:
        tmp = Path(tempfile.mkdtemp(prefix=f".{final.name}.", suffix=".partial", dir=final.parent))
        os.chmod(tmp, dir_mode())
        yield tmp
        if final.exists():
            old = _move_aside(final)
            _replace(tmp, final)
            _remove_or_warn(old)
        else:
            _replace(tmp, final)
    except BaseException:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
        raise


def _replace(src: Path, dst: Path) -> None:
    """``os.replace``, then an fsync of the folder so the rename itself survives a power loss; an
    error names ``dst`` (the user's path), not the hidden temp name."""
    try:
        os.replace(src, dst)
    except OSError as e:
        raise OSError(e.errno, f"{e.strerror} (replacing it with {src.name})", str(dst)) from None
    fsync_directory(dst.parent)


def fsync_directory(path: Path) -> None:
    """Flush a folder's entries (renames, new names) to disk; best effort, since some file systems
    and Windows cannot open a folder for fsync (about 0.1 ms on ext4)."""
    with contextlib.suppress(OSError):
        fd = os.open(path, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def remove_directory(path: str | Path) -> None:
    """Take ``path`` away at once (renamed aside under a hidden name, then removed), so a reader
    sees the whole folder or none of it, never a half-deleted one."""
    _remove_or_warn(_move_aside(Path(path)))


def _move_aside(path: Path) -> Path:
    """Rename ``path`` to a fresh hidden ``.old`` name beside it (a fixed name could collide)."""
    old = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".old", dir=path.parent))
    _replace(path, old)
    return old


def _remove_or_warn(path: Path) -> None:
    shutil.rmtree(path, ignore_errors=True)
    if path.exists():
        logging.getLogger(__name__).warning("%s: could not remove the replaced copy (read-only files?); "
                                            "delete it by hand", path)


@contextlib.contextmanager
def atomic_file(path: str | Path) -> Iterator:
    """Yield a binary temp file beside ``path`` to stream into; on success it is fsynced and renamed
    to ``path`` (with the mode an ordinary ``open`` gives under the umask); on failure removed."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = None
    try:
        try:
            fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
        except OSError as e:  # it names its random temp file; the user knows the file they asked for
            raise OSError(e.errno, f"{e.strerror} (writing it through a temporary file in its folder)",
                          str(path)) from None
        with os.fdopen(fd, "wb") as f:
            os.fchmod(f.fileno(), file_mode())
            yield f
            f.flush()
            os.fsync(f.fileno())
        _replace(Path(tmp), path)
    except BaseException:
        if tmp is not None:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp)
        raise
