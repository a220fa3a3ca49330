"""Checked feather reads: an unreadable file or a missing column becomes an AV2LogError naming the file."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.feather as feather

from converters.av2.errors import AV2LogError


def read_columns(path: Path, columns: Sequence[str]) -> dict[str, np.ndarray]:
    """The named columns of a feather file as numpy arrays (strings as object arrays)."""
    if not path.is_file():
        raise AV2LogError(path, "file not found")
    try:
        table = feather.read_table(path)
    except (pa.ArrowException, OSError, ValueError) as e:
        raise AV2LogError(path, f"unreadable feather file ({type(e).__name__}: {e})") from e
    missing = [c for c in columns if c not in table.column_names]
    if missing:
        raise AV2LogError(path, f"missing column(s) {missing}; has {table.column_names}")
    out = {}
    for c in columns:
        col = table.column(c)
        if col.null_count:
            row = int(np.flatnonzero(col.is_null().to_numpy(zero_copy_only=False))[0])
            raise AV2LogError(path, f"null (missing) value in column '{c}' at row {row}")
        out[c] = col.to_numpy(zero_copy_only=False)
    return out


def require_finite(path: Path, cols: dict[str, np.ndarray], names: Sequence[str]) -> None:
    """Raise naming the file, row and column of the first NaN/Inf among ``names``."""
    for name in names:
        bad = ~np.isfinite(np.asarray(cols[name], dtype=np.float64))
        if bad.any():
            row = int(np.flatnonzero(bad)[0])
            raise AV2LogError(path, f"non-finite value {cols[name][row]!r} in column '{name}' at row {row}")
