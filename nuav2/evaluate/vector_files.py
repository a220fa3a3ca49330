"""Readers of MapTR-format vector files: predictions (``nuscmap_results.json``) and GT files.

One reader for ``nuav2 eval`` and ``nuav2 viz --pred``, so a file that one accepts the other
draws or scores the same way; every error names the file and the record. Points come back as x, y:
a file with [x, y, z] points (MapTRv2's 3-D variants) is read with z dropped, as MapTR's 2-D
evaluation scores it.
"""

from __future__ import annotations

import contextlib
import json
from pathlib import Path

import numpy as np


def _parse_vector(vec, where: str, is_pred: bool) -> tuple:
    """(cls_name, (N, 2) float64 x, y points[, confidence]) of one vector record; a ValueError naming
    ``where`` (file, sample, vector index) and the field on anything else, so no bad record
    reaches the evaluator or the drawing code as an unhashable name or a None score."""
    if not isinstance(vec, dict) or "pts" not in vec or "cls_name" not in vec:
        raise ValueError(f"{where}: each vector needs 'pts' and 'cls_name'")
    name = vec["cls_name"]
    if not isinstance(name, str):
        raise ValueError(f"{where}: 'cls_name' must be a string, got {_show(name)}")
    pts = _points(vec["pts"], where)
    if not is_pred:
        return (name, pts)
    if "confidence_level" not in vec:
        raise ValueError(f"{where}: prediction vector has no 'confidence_level'")
    return (name, pts, _confidence(vec["confidence_level"], where))


def _show(value) -> str:
    """A short repr of a bad value for a one-line message."""
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _points(pts, where: str) -> np.ndarray:
    """'pts' ([x, y] or [x, y, z] points) as (N, 2) finite float64 x, y, z dropped (an empty list: no
    points); numpy converts well-formed lists in one pass (true/false among numbers, which it would take
    as 1/0, are looked for by identity: 1.5 us a vector), anything else gets a message saying which
    point is wrong and how."""
    arr = None
    if isinstance(pts, list) and pts:
        with contextlib.suppress(ValueError, TypeError):
            arr = np.asarray(pts)
    elif isinstance(pts, list):
        return np.zeros((0, 2))
    odd = arr is None or arr.dtype.kind not in "iuf" or arr.ndim != 2 or arr.shape[1] not in (2, 3)
    if odd or _holds_bool(pts):
        problem = _points_problem(pts)
        if problem:
            raise ValueError(f"{where}: 'pts' {problem}")
    if odd:
        arr = np.array(pts, dtype=object)  # well-formed, but numbers numpy did not take as such
    try:
        arr = arr.astype(np.float64)
    except OverflowError:
        raise ValueError(f"{where}: 'pts' holds a number too large for a float") from None
    if not np.isfinite(arr).all():
        raise ValueError(f"{where}: 'pts' holds NaN or Inf")
    return np.ascontiguousarray(arr[:, :2])


def _holds_bool(pts: list) -> bool:
    for p in pts:
        for x in p:
            if x is True or x is False:
                return True
    return False


def _points_problem(pts) -> str | None:
    """Why ``pts`` is not a list of [x, y] (or [x, y, z]) number lists; None if it is."""
    if not isinstance(pts, list):
        return f"must be a list of [x, y] points, got {_show(pts)}"
    for i, p in enumerate(pts):
        if not isinstance(p, list) or len(p) not in (2, 3):
            return f"point {i} must be [x, y] (or [x, y, z]), got {_show(p)}"
        bad = [x for x in p if not _is_number(x)]
        if bad:
            return f"point {i} holds {_show(bad[0])}, not a number"
    widths = sorted({len(p) for p in pts})
    return f"points must all have 2 (or all 3) coordinates, got lengths {widths}" if len(widths) > 1 else None


def _confidence(value, where: str) -> float:
    """'confidence_level' as a finite float."""
    if not _is_number(value) or not np.isfinite(value):
        raise ValueError(f"{where}: 'confidence_level' must be a finite number, got {_show(value)}")
    return float(value)


def _is_number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def _entries(data, path: Path, key: str):
    """(token, vectors) pairs from a MapTR-style file: a list of {sample_token, vectors} or a dict."""
    if isinstance(data, dict) and key not in data and "meta" in data:
        raise ValueError(f"{path}: no '{key}' field (a MapTR file holds 'meta' and '{key}')")
    body = data.get(key, data) if isinstance(data, dict) else data
    if isinstance(body, dict):  # token -> vectors, or token -> {"vectors": vectors}
        return [(tok, rec["vectors"] if isinstance(rec, dict) and "vectors" in rec else rec)
                for tok, rec in body.items()]
    if isinstance(body, list):
        out = []
        for i, rec in enumerate(body):
            if not isinstance(rec, dict) or "sample_token" not in rec or "vectors" not in rec:
                raise ValueError(f"{path}: {key}[{i}] needs 'sample_token' and 'vectors'")
            if not isinstance(rec["sample_token"], str):
                raise ValueError(f"{path}: {key}[{i}] 'sample_token' must be a string, "
                                 f"got {_show(rec['sample_token'])}")
            out.append((rec["sample_token"], rec["vectors"]))
        return out
    raise ValueError(
        f"{path}: '{key}' must be a list of {{sample_token, vectors}} or a dict token -> vectors"
    )


class _RepeatedKey(ValueError):
    pass


def _unique_keys(pairs: list) -> dict:
    """A JSON object as a dict, refusing a key given twice (json.loads would keep the last silently:
    a sample's predictions replaced by a later empty list)."""
    out = dict(pairs)
    if len(out) < len(pairs):
        seen: set = set()
        key = next(k for k, _ in pairs if k in seen or seen.add(k))
        raise _RepeatedKey(f"key {_show(key)} appears twice in one JSON object")
    return out


def _load_vector_file(path: str | Path, key: str, is_pred: bool) -> dict:
    path = Path(path)
    try:
        data = json.loads(path.read_text(), object_pairs_hook=_unique_keys)
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: file not found") from None
    except _RepeatedKey as e:
        raise ValueError(f"{path}: {e}") from None
    except json.JSONDecodeError as e:
        raise ValueError(f"{path}: not valid JSON ({e})") from None
    except RecursionError:
        raise ValueError(f"{path}: not valid JSON here (nested too deeply)") from None
    except UnicodeDecodeError as e:
        raise ValueError(f"{path}: not UTF-8 text ({e.reason} at byte {e.start})") from None
    out: dict = {}
    for token, vectors in _entries(data, path, key):
        if token in out:
            raise ValueError(f"{path}: sample_token {token} appears twice")
        if not isinstance(vectors, list):
            raise ValueError(f"{path}: vectors of sample {token} must be a list")
        out[token] = [
            _parse_vector(v, f"{path}: sample {token} vector {j}", is_pred) for j, v in enumerate(vectors)
        ]
    return out


def load_predictions(path: str | Path) -> dict[str, list[tuple[str, np.ndarray, float]]]:
    """Read MapTR's ``nuscmap_results.json`` ({'meta', 'results': [...]}) or a dict of lists."""
    return _load_vector_file(path, "results", is_pred=True)


def load_gt_file(path: str | Path) -> dict[str, list[tuple[str, np.ndarray]]]:
    """Read a MapTR GT file ({'GTs': [{sample_token, vectors: [{pts, cls_name}]}]})."""
    return _load_vector_file(path, "GTs", is_pred=False)
