"""Checks of what the analysis commands (``split``, ``infos``, ``eval``, ``viz``) are given.

Why: these commands hand a database to nuscenes-devkit and write their result only after all
the work. The devkit's errors on a damaged table name neither the file nor the record (a bare
``KeyError`` of a token, a JSON decode position), and a bad output path used to surface at the
very end, naming a temp file. So: an output path is checked before the work, and when the
work fails on a database whose tables are malformed, the error names the table file and the
record instead (found by the conformance checker, run only then: the happy path pays nothing).
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator, Sequence
from pathlib import Path

# Problems of the conformance checker that stop the devkit (or the code reading its records):
# missing or unparsable tables, records of the wrong shape, tokens that resolve to nothing, numbers
# that are NaN/Inf or of the wrong length, rotations that are no unit quaternion.
STRUCTURAL_CHECKS = ("layout", "missing_table", "bad_json", "schema", "duplicate_token", "foreign_key",
                     "linked_list", "map_table", "non_finite", "shape", "quaternion")


def refuse_repeats(flag: str, values: Sequence[str]) -> None:
    """A list flag naming a value twice (``--classes``, ``--cameras``) is a UsageError naming them."""
    from nuav2.cli import UsageError

    twice = sorted({v for v in values if values.count(v) > 1})
    if twice:
        raise UsageError(f"{flag}: {', '.join(twice)} given more than once")


def out_path_problem(path: str | Path) -> str | None:
    """What makes ``path`` unusable as an output file, or None.

    Missing folders are fine (the atomic writers create them), so the nearest existing
    ancestor must be a folder this process may write in.
    """
    path = Path(path)
    if path.is_dir():
        return "is a folder; give a file path"
    if path.name in ("", ".", ".."):
        return "names no file"
    ancestor = path.parent
    while not ancestor.exists() and ancestor != ancestor.parent:
        if ancestor.is_symlink():
            return f"{ancestor} is a dangling symbolic link"
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        return f"{ancestor} is not a folder"
    if not os.access(ancestor, os.W_OK | os.X_OK):
        return f"cannot write in folder {ancestor} (permission denied)"
    return None


def require_out_path(path: str | Path | None, flag: str = "--out") -> None:
    """Refuse an unusable output path before the work: a UsageError naming ``flag`` and the path as given."""
    from nuav2.cli import UsageError

    problem = out_path_problem(path) if path else None
    if problem:
        raise UsageError(f"{flag} {path}: {problem}")


def table_problem(dataroot: str | Path, version: str) -> str | None:
    """The first structural problem of ``dataroot/version``'s tables as one line naming the table
    file and the record, or None when the tables are well-formed."""
    from nuav2.nuscenes_db.validate import validate_database

    report = validate_database(dataroot, version, check_files=False, check_images=False, max_per_kind=1)
    found = [p for p in report.problems if p.check in STRUCTURAL_CHECKS]
    if not found:
        return None
    p = found[0]
    where = " ".join(s for s in (f"record {p.token}" if p.token else "", p.field) if s)
    table = _table_file(Path(dataroot), version, p.table)
    what = f"{where + ': ' if where else ''}{p.message}"
    more = report.n_problems - 1
    rest = f"; {more} more problem(s)" if more else ""
    return (f"{what if str(table) in what else f'{table}: {what}'} (malformed table{rest}; "
            f"'nuav2 validate {dataroot} --version {version}' lists them)")


def _table_file(dataroot: Path, version: str, table: str) -> Path:
    """The file a problem's ``table`` names: ``expansion/LOC`` is ``maps/expansion/LOC.json``."""
    if not table:
        return dataroot / version
    if table.startswith("expansion/"):
        return dataroot / "maps" / f"{table}.json"
    return dataroot / version / f"{table}.json"


@contextlib.contextmanager
def diagnosed_tables(dataroot: str | Path, version: str) -> Iterator[None]:
    """Run database work; if it fails and the tables are malformed, raise a ValueError naming the
    table file and what is wrong instead of the devkit's bare error (which is chained)."""
    try:
        yield
    except Exception as e:
        try:
            problem = table_problem(dataroot, version)
        except Exception:  # noqa: BLE001 - the diagnosis must never hide the original error
            problem = None
        if problem is None:
            raise
        raise ValueError(problem) from e
