"""What rewriting a log's data files does to the databases already in OUT.

A log's images and LiDAR files have the same names whatever the options or ``--version``
(``writer.data_filename``), so a run that writes a log again replaces files other tables may
point at. These checks run before the first file is written and after the last log finished, so
no table ever names a file that is gone or that another conversion overwrote.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Iterable
from pathlib import Path

from nuav2.atomic import remove_directory
from nuav2.nuscenes_db import shards as sh
from nuav2.nuscenes_db.map_frame import location_id
from nuav2.nuscenes_db.merge import LOGS_FILE

log = logging.getLogger(__name__)
DATA_DIRS = ("samples", "sweeps")


def other_versions_using(out: Path, version: str, fingerprint: str, rewritten: Iterable[str]) -> list[str]:
    """``version/log`` for each log this run rewrites that another version in OUT holds converted
    with other options: rewriting would change the images under that version's tables."""
    rewritten = set(rewritten)
    clashes = []
    for other in sh.shard_versions(out):
        if other == version:
            continue
        for log_id, path in sh.existing_shards(out, other).items():
            if log_id in rewritten and not sh.is_complete(path, fingerprint):
                clashes.append(f"{other}/{log_id}")
    return clashes


def retire_tables_naming(folder: Path, rewritten: Iterable[str]) -> list[str]:
    """Remove the tables in ``folder`` when they name a log this run rewrites (its files are replaced
    now, and removed if the log then fails): the merge writes them anew; until it does, OUT holds no
    tables that name a missing or changed file. Returns the logs that caused it."""
    path = Path(folder) / LOGS_FILE
    if not path.is_file():
        return []
    try:
        named = {r.get("log_id") for r in json.loads(path.read_text()) if isinstance(r, dict)}
    except (OSError, ValueError, TypeError):
        named = set(rewritten)  # unreadable: treat as naming them all; the merge rewrites it anyway
    hit = sorted(named & set(rewritten))
    if hit:
        names = ", ".join(hit[:3]) + (", ..." if len(hit) > 3 else "")
        log.warning("%s: removing these tables before %d of their logs are written again (%s); this run's "
                    "merge writes them anew", folder, len(hit), names)
        remove_directory(folder)
    return hit


def remove_log_files(out: Path, version: str, log_id: str) -> int:
    """Remove a failed log's data files (and temp files a killed worker left beside them), except
    those the log's shard in another version still lists; returns how many were removed."""
    keep = sh.files_other_versions_list(out, version, log_id)
    removed = 0
    for top in DATA_DIRS:
        base = Path(out) / top
        if not base.is_dir():
            continue
        for channel in base.iterdir():
            prefix = f"{log_id}__{channel.name}__"
            if not channel.is_dir():
                continue
            for f in channel.iterdir():
                rel = f"{top}/{channel.name}/{f.name}"
                if f.name.lstrip(".").startswith(prefix) and rel not in keep and not f.is_dir():
                    f.unlink(missing_ok=True)
                    removed += 1
    return removed


def shared_locations(out: Path, log_ids: Iterable[str]) -> list[list[str]]:
    """Groups of distinct logs (this run's and every shard's in OUT, any version) whose map location
    would be one name: the later log's map files would overwrite the earlier one's."""
    names = set(log_ids)
    for version in sh.shard_versions(out):
        names |= set(sh.existing_shards(out, version))
    groups: dict[str, list[str]] = {}
    for name in sorted(names):
        groups.setdefault(location_id(name), []).append(name)
    return [g for g in groups.values() if len(g) > 1]
