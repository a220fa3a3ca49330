"""Readers of MapTR-format vector files: predictions (``nuscmap_results.json``) and GT files.

One reader for ``nuav2 eval`` and ``nuav2 viz --pred``, so a file that one accepts the other
draws or scores the same way; every error names the file and the record.
"""

from __future__ import annotations

import json
from pathlib import Path


def _parse_vector(vec, where: str, is_pred: bool):
    if not isinstance(vec, dict) or "pts" not in vec or "cls_name" not in vec:
        raise ValueError(f"{where}: each vector needs 'pts' and 'cls_name'")
    if not is_pred:
        return (vec["cls_name"], vec["pts"])
    if "confidence_level" not in vec:
        raise ValueError(f"{where}: prediction vector has no 'confidence_level'")
    return (vec["cls_name"], vec["pts"], vec["confidence_level"])


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
            out.append((rec["sample_token"], rec["vectors"]))
        return out
    raise ValueError(
        f"{path}: '{key}' must be a list of {{sample_token, vectors}} or a dict token -> vectors"
    )


def _load_vector_file(path: str | Path, key: str, is_pred: bool) -> dict:
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: file not found") from None
    except json.JSONDecodeError as e:
        raise ValueError(f"{path}: not valid JSON ({e})") from None
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


def load_predictions(path: str | Path) -> dict[str, list[tuple[str, list, float]]]:
    """Read MapTR's ``nuscmap_results.json`` ({'meta', 'results': [...]}) or a dict of lists."""
    return _load_vector_file(path, "results", is_pred=True)


def load_gt_file(path: str | Path) -> dict[str, list[tuple[str, list]]]:
    """Read a MapTR GT file ({'GTs': [{sample_token, vectors: [{pts, cls_name}]}]})."""
    return _load_vector_file(path, "GTs", is_pred=False)
