"""Checked feather reads: an unreadable file, a missing column or a column of the wrong type becomes
an AV2LogError naming the file (and the column)."""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.feather as feather

from converters.av2.errors import AV2LogError, require_file

# What a column of ``read_columns`` must hold (its Arrow type):
INTEGER = "integer"  # timestamps, counts, indices, pixel sizes: an integer type (never NaN, never rounded)
NUMBER = "number"  # measurements: an integer or floating type
TEXT = "text"  # names and ids: any type (the reader turns them into str)


def _type_problem(kind: str, typ: pa.DataType) -> str | None:
    if kind == INTEGER:
        return None if pa.types.is_integer(typ) else "an integer type"
    if kind == NUMBER:
        numeric = pa.types.is_integer(typ) or pa.types.is_floating(typ)
        return None if numeric else "an integer or floating type"
    if kind == TEXT:
        return None
    raise ValueError(f"unknown column kind {kind!r}")


def read_columns(path: Path, columns: Mapping[str, str]) -> dict[str, np.ndarray]:
    """The named columns (name -> INTEGER / NUMBER / TEXT) of a feather file as numpy arrays
    (strings as object arrays)."""
    require_file(path)
    try:
        table = feather.read_table(path)
    except (pa.ArrowException, OSError, ValueError) as e:
        raise AV2LogError(path, f"unreadable feather file ({type(e).__name__}: {e})") from e
    missing = [c for c in columns if c not in table.column_names]
    if missing:
        raise AV2LogError(path, f"missing column(s) {missing}; has {table.column_names}")
    out = {}
    for c, kind in columns.items():
        col = table.column(c)
        expected = _type_problem(kind, col.type)
        if expected:
            raise AV2LogError(path, f"column '{c}' has type {col.type}, expected {expected}")
        if col.null_count:
            row = int(np.flatnonzero(col.is_null().to_numpy(zero_copy_only=False))[0])
            raise AV2LogError(path, f"null (missing) value in column '{c}' at row {row}")
        out[c] = col.to_numpy(zero_copy_only=False)
    return out


def require_finite(path: Path, cols: dict[str, np.ndarray], names: Iterable[str]) -> None:
    """Raise naming the file, row and column of the first NaN/Inf among ``names``."""
    for name in names:
        bad = ~np.isfinite(np.asarray(cols[name], dtype=np.float64))
        if bad.any():
            row = int(np.flatnonzero(bad)[0])
            raise AV2LogError(path, f"non-finite value {cols[name][row]!r} in column '{name}' at row {row}")
