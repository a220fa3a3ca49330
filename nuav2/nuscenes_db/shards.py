"""Per-log shards: one directory per converted log, renamed into place only when complete.

A shard holds the log's per-log tables (one JSON file each) and ``meta.json``. A killed
conversion leaves at most a ``.partial`` temp directory, never a shard, so a rerun redoes
exactly the logs without a complete shard. The shard records the *fingerprint* of the
options that produced it; a shard from other options is redone, not merged.
"""

from __future__ import annotations

import contextlib
import json
import logging
import re
from pathlib import Path

from nuav2.atomic import atomic_directory
from nuav2.nuscenes_db.tables import PER_LOG_TABLES
from nuav2.nuscenes_db.writer import WRITER_FORMAT, LogShard

log = logging.getLogger(__name__)

SHARDS_DIRNAME = ".nuav2_shards"
META_FILE = "meta.json"
_SAFE_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]*$")


class ShardError(ValueError):
    """A shard directory is unreadable or inconsistent; the message names the file."""


def shard_root(dataroot: Path, version: str) -> Path:
    return Path(dataroot) / SHARDS_DIRNAME / version


def shard_dir(dataroot: Path, version: str, log_id: str) -> Path:
    if not _SAFE_NAME.match(log_id):
        raise ValueError(f"log id {log_id!r} is not usable as a directory name")
    return shard_root(dataroot, version) / log_id


def save_shard(path: Path, shard: LogShard, fingerprint: str) -> None:
    """Write the shard's files into a temp directory, then rename it to ``path`` in one step.

    A shard it replaces (the log converted before with other options) may list data files this
    one does not (other channels, other sample/sweep folders): those are removed after the
    rename, unless the same log's shard of another version in this OUT still lists them."""
    before = data_files(path)
    meta = {"format": WRITER_FORMAT, "fingerprint": fingerprint, "log_id": shard.log_id,
            "channels": shard.channels, "meta": shard.meta}
    with atomic_directory(path) as tmp:
        for table in PER_LOG_TABLES:
            (tmp / f"{table}.json").write_text(json.dumps(shard.tables[table], ensure_ascii=False))
        (tmp / META_FILE).write_text(json.dumps(meta, ensure_ascii=False, indent=1))
    stale = before - {r["filename"] for r in shard.tables["sample_data"]}
    if stale:
        _remove_stale_files(path, stale)


def data_files(path: Path) -> set[str]:
    """Dataroot-relative data files a shard's sample_data lists (none when absent or unreadable)."""
    if not (Path(path) / "sample_data.json").is_file():
        return set()
    try:
        return {r["filename"] for r in read_table(path, "sample_data")}
    except (ShardError, KeyError, TypeError):
        return set()


def shard_versions(dataroot: Path) -> list[str]:
    """The versions that have a shard folder in ``dataroot``, sorted."""
    root = Path(dataroot) / SHARDS_DIRNAME
    return sorted(p.name for p in root.iterdir() if p.is_dir()) if root.is_dir() else []


def files_other_versions_list(dataroot: Path, version: str, log_id: str) -> frozenset[str]:
    """Data files of ``log_id`` that its shard in another version lists: data file names do not
    depend on the version, so those files are shared and must stay."""
    listed: set[str] = set()
    for other in shard_versions(dataroot):
        if other != version:
            listed |= data_files(shard_root(dataroot, other) / log_id)
    return frozenset(listed)


def _remove_stale_files(path: Path, stale: set[str]) -> None:
    dataroot = Path(path).parent.parent.parent  # OUT/.nuav2_shards/<version>/<log id>
    stale -= files_other_versions_list(dataroot, Path(path).parent.name, Path(path).name)
    for rel in sorted(stale):
        with contextlib.suppress(FileNotFoundError):
            (dataroot / rel).unlink()
    log.info("%s: removed %d data file(s) the log's earlier conversion wrote and this one does not",
             Path(path).name, len(stale))


def read_meta(path: Path) -> dict:
    f = Path(path) / META_FILE
    try:
        meta = json.loads(f.read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise ShardError(f"{f}: unreadable shard metadata ({e})") from e
    for key in ("format", "fingerprint", "log_id", "channels", "meta"):
        if key not in meta:
            raise ShardError(f"{f}: missing field '{key}'")
    return meta


def is_complete(path: Path, fingerprint: str) -> bool:
    """True when ``path`` is a finished shard of the current writer format and these options."""
    if not (Path(path) / META_FILE).is_file():
        return False
    try:
        meta = read_meta(path)
    except ShardError:
        return False
    return (meta["format"] == WRITER_FORMAT and meta["fingerprint"] == fingerprint
            and all((Path(path) / f"{t}.json").is_file() for t in PER_LOG_TABLES))


def existing_shards(dataroot: Path, version: str) -> dict[str, Path]:
    """{log id: shard directory} of every shard under ``dataroot`` for ``version`` (temp dirs and
    retired shards skipped)."""
    root = shard_root(dataroot, version)
    if not root.is_dir():
        return {}
    return {p.name: p for p in sorted(root.iterdir())
            if p.is_dir() and _SAFE_NAME.match(p.name) and (p / META_FILE).is_file()}


def retire_shard(path: Path) -> None:
    """Before a log is written again (other options): drop its old shard's metadata, so that if this
    attempt fails (its cleanup may remove files it overwrote) the old shard is never resumed or merged
    again. Its sample_data stays, so the next successful save still removes its stale data files."""
    with contextlib.suppress(FileNotFoundError):
        (Path(path) / META_FILE).unlink()


def read_table(path: Path, table: str) -> list[dict]:
    f = Path(path) / f"{table}.json"
    try:
        records = json.loads(f.read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise ShardError(f"{f}: unreadable shard table ({e})") from e
    if not isinstance(records, list):
        raise ShardError(f"{f}: a table must be a JSON list")
    return records
