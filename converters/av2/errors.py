"""The one exception the AV2 reader raises for bad input, so callers can skip a broken log."""

from __future__ import annotations

from pathlib import Path


class AV2LogError(ValueError):
    """An AV2 log file or directory is missing or malformed; the message names the path and what is wrong."""

    def __init__(self, path: str | Path, reason: str) -> None:
        self.path = Path(path)
        self.reason = reason
        super().__init__(f"{self.path}: {reason}")
