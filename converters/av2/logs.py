"""Finding AV2 log directories under a split dir, a ``sensor/`` dir, a dataset root, or one log."""

from __future__ import annotations

import os
from pathlib import Path

from converters.av2.errors import AV2LogError
from converters.av2.poses import POSE_FILE

SPLITS = ("train", "val", "test")


def is_log_dir(path: Path) -> bool:
    return (path / POSE_FILE).is_file()


def _logs_in(split_dir: Path) -> list[Path]:
    """Log dirs in ``split_dir``; hidden ones are skipped (an interrupted atomic write leaves a
    ``.<log id>.<tmp>.partial`` dir that may already hold the pose file). A dir that cannot be
    looked into is kept: its conversion fails and is reported, and the other logs still convert."""
    return sorted(p for p in split_dir.iterdir()
                  if p.is_dir() and not p.name.startswith(".") and maybe_log_dir(p))


# What else a log dir holds: one that has these but no pose file is a damaged log (a partial
# download), kept so that its conversion fails and is reported, not silently left out.
_LOG_PARTS = ("sensors", "calibration", "annotations.feather", "map")


def maybe_log_dir(path: Path) -> bool:
    """A log dir, or what is left of one (its parts without the pose file)."""
    try:
        return is_log_dir(path) or any((path / part).exists() for part in _LOG_PARTS)
    except PermissionError:
        return True


def find_logs(src: Path) -> list[Path]:
    """Log directories under ``src``, sorted (splits in train, val, test order).

    ``src`` may be one log, a split dir holding logs, a ``sensor/`` dir holding train/val/test,
    or the dataset root holding ``sensor/``.
    """
    src = Path(os.path.abspath(src))  # `.` / `..` name no log; the report names absolute paths
    if not src.is_dir():
        raise AV2LogError(src, "not a directory")
    if is_log_dir(src):
        return [src]
    if (src / "sensor").is_dir():
        src = src / "sensor"
    splits = [src / s for s in SPLITS if (src / s).is_dir()]
    logs = [p for s in splits for p in _logs_in(s)] if splits else _logs_in(src)
    if not logs:
        raise AV2LogError(src, f"no AV2 logs found (a log dir holds {POSE_FILE}; looked in {src} "
                               f"and its {'/'.join(SPLITS)} subdirectories)")
    return logs


def split_of(log_dir: Path) -> str:
    """Source split name: the train/val/test dir the log sits in, else the av2 sensor split list
    that names its log id (a log copied out of its split dir keeps its split), else ''."""
    parent = log_dir.absolute().parent.name
    return parent if parent in SPLITS else published_split(log_dir.name)


def published_split(log_id: str) -> str:
    """The split of ``log_id`` in av2's published sensor split lists, '' when none names it."""
    from av2.datasets.sensor.splits import TEST, TRAIN, VAL

    return next((name for name, ids in zip(SPLITS, (TRAIN, VAL, TEST)) if log_id in ids), "")
