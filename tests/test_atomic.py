"""Atomic writes: nothing half-written or hidden is left behind, and errors name the user's path."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest

from nuav2.atomic import atomic_directory, atomic_write_bytes


def _hidden(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


def test_a_directory_is_replaced_even_beside_a_stale_copy_of_an_earlier_replace(tmp_path: Path):
    """An earlier replace that could not delete its old copy (read-only files) left ``.v.old``;
    every later replace then failed with "Directory not empty"."""
    final = tmp_path / "v"
    stale = tmp_path / ".v.old"
    (stale / "sub").mkdir(parents=True)
    (stale / "sub" / "table.json").write_text("[]")
    for text in ("first", "second", "third"):
        with atomic_directory(final) as tmp:
            (tmp / "table.json").write_text(text)
        assert (final / "table.json").read_text() == text
    assert _hidden(tmp_path) == [".v.old"]  # only the stale one; each replace removed its own copy


def test_a_failed_rename_names_the_target_and_leaves_no_temp_file(tmp_path: Path):
    (tmp_path / "out.json").mkdir()  # a directory where the file should go
    with pytest.raises(OSError) as err:
        atomic_write_bytes(tmp_path / "out.json", b"{}")
    assert err.value.filename == str(tmp_path / "out.json") and err.value.filename2 is None
    assert _hidden(tmp_path) == []
    with pytest.raises(RuntimeError), atomic_directory(tmp_path / "d") as tmp:
        (tmp / "x").write_text("x")
        raise RuntimeError("the writer failed")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.json"]


def test_each_rename_is_made_durable_by_an_fsync_of_its_folder(tmp_path: Path, monkeypatch):
    """A rename lives in the folder's entries: without an fsync of the folder a power loss can
    bring back the old file (or no file) even though the new one's bytes were flushed."""
    synced: list[tuple[int, int]] = []
    real_fsync = os.fsync

    def recording_fsync(fd: int) -> None:
        st = os.fstat(fd)
        if stat.S_ISDIR(st.st_mode):
            synced.append((st.st_dev, st.st_ino))
        real_fsync(fd)

    monkeypatch.setattr(os, "fsync", recording_fsync)
    sub = tmp_path / "tables"
    atomic_write_bytes(sub / "scene.json", b"[]")
    folder = os.stat(sub)
    assert (folder.st_dev, folder.st_ino) in synced
    synced.clear()
    with atomic_directory(tmp_path / "shard") as d:
        (d / "x").write_bytes(b"1")
    parent = os.stat(tmp_path)
    assert (parent.st_dev, parent.st_ino) in synced
