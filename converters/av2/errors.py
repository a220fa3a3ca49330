"""The one exception the AV2 reader raises for bad input, so callers can skip a broken log."""

from __future__ import annotations

from pathlib import Path


class AV2LogError(ValueError):
    """An AV2 log file or directory is missing or malformed; the message names the path and what is wrong."""

    def __init__(self, path: str | Path, reason: str) -> None:
        self.path = Path(path)
        self.reason = reason
        super().__init__(f"{self.path}: {reason}")


def require_file(path: Path) -> None:
    """Raise naming ``path`` unless it is a regular file (or a symlink to one)."""
    if path.is_file():
        return
    if path.is_symlink():
        reason = "not a readable file (dangling symlink or symlink loop)"
    elif path.is_dir():
        reason = "not a readable file (a directory)"
    elif path.exists():
        reason = "not a readable file (not a regular file)"
    else:
        reason = "file not found"
    raise AV2LogError(path, reason)
