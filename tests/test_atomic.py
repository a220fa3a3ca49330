"""Atomic writes: nothing half-written or hidden is left behind, and errors name the user's path."""

from __future__ import annotations

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
