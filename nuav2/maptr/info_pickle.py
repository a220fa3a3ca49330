"""The info ``.pkl`` written one scene at a time: ``{"infos": [...], "metadata": {...}}`` as one pickle
whose bytes do not depend on how many processes (or Ray workers) built its records.

Pickle protocol 3 has no framing and names its memo slots explicitly (BINPUT n), so each record
pickled on its own, without its PROTO and STOP opcodes, can follow the previous one in the same
stream: a record's memo slots simply overwrite the previous record's. The file is built as
PROTO 3, EMPTY_DICT, MARK, "infos", EMPTY_LIST, (record, APPEND)..., "metadata", {...},
SETITEMS, STOP. ``pickle.load`` (and MapTR's ``mmcv.load``) read it as the plain dict. Records are
never held together, so memory stays bounded whatever the number of samples.
"""

from __future__ import annotations

import pickle
import struct
from pathlib import Path
from typing import BinaryIO

PROTOCOL = 3  # MapTR's mmcv writes protocol 2; 3 adds raw bytes for numpy arrays and still has explicit memo
_APPEND, _MARK, _SETITEMS, _EMPTY_DICT, _EMPTY_LIST, _STOP = b"a", b"(", b"u", b"}", b"]", b"."


def record_bytes(obj) -> bytes:
    """``obj`` pickled alone, without PROTO and STOP, followed by APPEND: one list item of the stream."""
    data = pickle.dumps(obj, protocol=PROTOCOL)
    assert data[:2] == bytes([pickle.PROTO[0], PROTOCOL]) and data[-1:] == _STOP
    return data[2:-1] + _APPEND


def _key(name: str) -> bytes:
    raw = name.encode()
    return pickle.BINUNICODE + struct.pack("<I", len(raw)) + raw


class InfoPickleStream:
    """Writes the header, then :meth:`add` record bytes in order, then :meth:`close` the metadata."""

    def __init__(self, f: BinaryIO) -> None:
        self.f, self.count = f, 0
        f.write(pickle.PROTO + bytes([PROTOCOL]) + _EMPTY_DICT + _MARK + _key("infos") + _EMPTY_LIST)

    def add(self, records: bytes, count: int) -> None:
        """``records``: the concatenated :func:`record_bytes` of ``count`` records."""
        self.f.write(records)
        self.count += count

    def close(self, metadata: dict) -> None:
        self.f.write(_key("metadata") + pickle.dumps(metadata, protocol=PROTOCOL)[2:-1] + _SETITEMS + _STOP)


def read_infos(path: str | Path) -> dict:
    with open(path, "rb") as f:
        return pickle.load(f)
