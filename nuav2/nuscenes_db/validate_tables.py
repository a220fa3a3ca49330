"""Table access for the conformance checker: loaded records, token indexes and typed, cached columns.

Columns are built with C-level ``map``/``set`` passes and foreign keys resolved to row indexes
once, so the checks (in ``validate_records``, ``validate_links``, ``validate_files``) are
numpy over whole tables. A value of the wrong type becomes ``None`` in its column (the schema
check reports it once) and is left out of the checks that depend on it.
"""

from __future__ import annotations

import contextlib
import itertools
import json
import re
from collections.abc import Callable
from pathlib import Path

import numpy as np

TABLES = ("category", "attribute", "visibility", "instance", "sensor", "calibrated_sensor", "ego_pose",
          "log", "scene", "sample", "sample_data", "sample_annotation", "map")
MODALITIES = ("camera", "lidar", "radar")
SCENE_NAME_RE = re.compile(r"^scene-\d{4}$")  # NuScenesCanBus asserts it
QUAT_TOL = 1e-6
LIDAR_ROW_BYTES = 5 * 4  # x, y, z, intensity, ring as float32

_S, _I, _B, _L = "str", "int", "bool", "list"
_TYPES = {_S: (str,), _I: (int,), _B: (bool,), _L: (list,)}
_TYPE_WORD = {_S: "a string", _I: "an integer", _B: "a boolean", _L: "a list"}
# Fields (besides ``token``) that the devkit, MapTR's converter or this checker read.
SCHEMA: dict[str, dict[str, str]] = {
    "category": {"name": _S, "description": _S},
    "attribute": {"name": _S, "description": _S},
    "visibility": {"level": _S, "description": _S},
    "instance": {"category_token": _S, "nbr_annotations": _I, "first_annotation_token": _S,
                 "last_annotation_token": _S},
    "sensor": {"channel": _S, "modality": _S},
    "calibrated_sensor": {"sensor_token": _S, "translation": _L, "rotation": _L, "camera_intrinsic": _L},
    "ego_pose": {"translation": _L, "rotation": _L, "timestamp": _I},
    "log": {"logfile": _S, "vehicle": _S, "date_captured": _S, "location": _S},
    "scene": {"name": _S, "description": _S, "log_token": _S, "nbr_samples": _I, "first_sample_token": _S,
              "last_sample_token": _S},
    "sample": {"timestamp": _I, "scene_token": _S, "prev": _S, "next": _S},
    "sample_data": {"sample_token": _S, "ego_pose_token": _S, "calibrated_sensor_token": _S, "filename": _S,
                    "fileformat": _S, "width": _I, "height": _I, "timestamp": _I, "is_key_frame": _B,
                    "prev": _S, "next": _S},
    "sample_annotation": {"sample_token": _S, "instance_token": _S, "attribute_tokens": _L,
                          "visibility_token": _S, "translation": _L, "size": _L, "rotation": _L,
                          "num_lidar_pts": _I, "num_radar_pts": _I, "prev": _S, "next": _S},
    "map": {"log_tokens": _L, "category": _S, "filename": _S},
}
FOREIGN_KEYS = (  # (table, field, target table)
    ("instance", "category_token", "category"), ("instance", "first_annotation_token", "sample_annotation"),
    ("instance", "last_annotation_token", "sample_annotation"),
    ("calibrated_sensor", "sensor_token", "sensor"),
    ("scene", "log_token", "log"), ("scene", "first_sample_token", "sample"),
    ("scene", "last_sample_token", "sample"), ("sample", "scene_token", "scene"),
    ("sample_data", "sample_token", "sample"), ("sample_data", "ego_pose_token", "ego_pose"),
    ("sample_data", "calibrated_sensor_token", "calibrated_sensor"),
    ("sample_annotation", "sample_token", "sample"), ("sample_annotation", "instance_token", "instance"),
    ("sample_annotation", "visibility_token", "visibility"))
LIDAR_NEEDED = "(MapTR and the detection eval read sample['data']['LIDAR_TOP'])"

AddProblem = Callable[[str, str, str, str, str], None]  # (table, token, field, message, check)


def read_json(path: Path):
    """Parse a JSON file as the devkit reads it: strict UTF-8 text, so a BOM or UTF-16 is an error.

    Raises OSError or ValueError only: nesting too deep for the parser becomes a ValueError too.
    """
    try:
        return json.loads(path.read_bytes().decode("utf-8"))
    except RecursionError:
        raise ValueError("JSON nested too deeply to parse") from None


class TableStore:
    """Holds the loaded tables, their token indexes and cached columns while checks run."""

    def __init__(self, dataroot: Path, version: str, report, progress: bool):
        self.dataroot = dataroot
        self.version = version
        self.table_root = dataroot / version
        self.add = report.add
        self.report = report
        self.progress = progress
        self.recs: dict[str, list[dict]] = {}
        self.index: dict[str, dict[str, int]] = {}
        self.usable: set[str] = set()  # tables that loaded as a JSON list
        self._cols: dict[tuple, list] = {}
        self._lookup: dict[str, dict[str, int]] = {}  # token index plus "" -> -1, for resolve()
        self._resolved: dict[tuple[str, str, str], np.ndarray] = {}

    def _load(self, table: str) -> None:
        path = self.table_root / f"{table}.json"
        self.recs[table], self.index[table] = [], {}
        if not path.is_file():
            self.add(table, "", "", f"table file missing: {path}", "missing_table")
            return
        try:
            data = read_json(path)
        except (OSError, ValueError) as e:
            self.add(table, "", "", f"cannot parse {path}: {e}", "bad_json")
            return
        if not isinstance(data, list):
            self.add(table, "", "", f"{path} holds a JSON {type(data).__name__}, not a list of records",
                     "bad_json")
            return
        if set(map(type, data)) - {dict}:
            for i, r in enumerate(data):
                if not isinstance(r, dict):
                    self.add(table, "", "", f"record #{i} is a {type(r).__name__}, not an object", "schema")
                    data[i] = {}
        toks = list(map(dict.get, data, itertools.repeat("token")))
        all_str = set(map(type, toks)) == {str}
        index = dict(zip(toks, range(len(toks)))) if all_str else {}
        if not all_str or len(index) != len(toks) or "" in index:
            index = {}  # something is wrong: find it record by record
            for i, tok in enumerate(toks):
                if not isinstance(tok, str) or not tok:
                    self.add(table, f"#{i}", "token", "no non-empty string token", "schema")
                elif tok in index:
                    self.add(table, tok, "token", f"duplicate token (records #{index[tok]} and #{i})",
                             "duplicate_token")
                else:
                    index[tok] = i
        self.recs[table], self.index[table] = data, index
        self.usable.add(table)
        self.report.table_counts[table] = len(data)

    def tokens(self, table: str) -> list[str]:
        return self.col(table, "token", _S, default="")

    def col(self, table: str, name: str, kind: str, default=None) -> list:
        """Column of ``name``; values of the wrong type (reported by the schema check) become ``default``.

        Columns are built with C-level ``map``/``set`` passes; per-value Python work happens only
        when a column holds a wrong type.
        """
        key = (table, name, kind, default)
        if key not in self._cols:
            if default is None:
                raw = list(map(dict.get, self.recs[table], itertools.repeat(name)))
                types = _TYPES[kind]
                if not set(map(type, raw)) <= set(types):
                    raw = [v if type(v) in types else None for v in raw]
                self._cols[key] = raw
            else:
                col = self.col(table, name, kind)
                self._cols[key] = [default if v is None else v for v in col] if None in col else col
        return self._cols[key]

    def resolve(self, table: str, name: str, target: str) -> np.ndarray:
        """Row index in ``target`` of each foreign key; -1 for "" and -2 for dangling or unreadable."""
        key = (table, name, target)
        if key not in self._resolved:
            if target not in self._lookup:
                self._lookup[target] = {**self.index.get(target, {}), "": -1}
            col = self.col(table, name, _S)
            rows = np.fromiter(map(self._lookup[target].get, col, itertools.repeat(-2)), dtype=np.int64,
                               count=len(col))
            rows.flags.writeable = False  # shared by every check
            self._resolved[key] = rows
        return self._resolved[key]

    def ints(self, table: str, name: str) -> tuple[np.ndarray, np.ndarray]:
        """Integer column as int64 plus a mask of rows where it was readable."""
        col = self.col(table, name, _I)
        if None not in col:
            with contextlib.suppress(OverflowError):
                return np.array(col, dtype=np.int64).reshape(len(col)), np.ones(len(col), dtype=bool)
        ok = np.fromiter((v is not None and -(2**63) <= v < 2**63 for v in col), dtype=bool, count=len(col))
        return np.fromiter((v if k else 0 for v, k in zip(col, ok)), dtype=np.int64, count=len(col)), ok

    def bools(self, table: str, name: str) -> tuple[np.ndarray, np.ndarray]:
        """Boolean column plus a mask of rows where it was readable."""
        col = self.col(table, name, _B)
        if None not in col:
            return np.array(col, dtype=bool).reshape(len(col)), np.ones(len(col), dtype=bool)
        return (np.fromiter((v is True for v in col), dtype=bool, count=len(col)),
                np.fromiter((v is not None for v in col), dtype=bool, count=len(col)))

    def vectors(self, table: str, name: str, width: int) -> tuple[np.ndarray, np.ndarray]:
        """(N, width) float64 of a numeric-list column and a mask of rows that are finite and well-formed."""
        col = self.col(table, name, _L)
        tokens = self.tokens(table)
        if None not in col and set(map(len, col)) == {width} and \
                set(map(type, itertools.chain.from_iterable(col))) <= {int, float}:
            arr = np.array(col, dtype=np.float64).reshape(len(col), width)
            formed = np.ones(len(col), dtype=bool)
        else:
            arr = np.full((len(col), width), np.nan)
            formed = np.zeros(len(col), dtype=bool)
            for i, v in enumerate(col):
                if v is None:
                    continue  # wrong type: reported by the schema check
                if len(v) == width and all(type(x) in (int, float) for x in v):
                    arr[i], formed[i] = v, True
                else:
                    self.add(table, tokens[i], name, f"must be a list of {width} numbers, got {v!r:.80}",
                             "shape")
        finite = np.all(np.isfinite(arr), axis=1)
        for i in np.flatnonzero(formed & ~finite):
            self.add(table, tokens[i], name, f"contains NaN or Inf: {col[i]}", "non_finite")
        return arr, finite

    def _sample_data_columns(self) -> dict[str, np.ndarray]:
        """Per sample_data row: sample, scene, log, channel and modality index (-1 where unresolvable)."""
        def via(child: np.ndarray, parent_of: np.ndarray) -> np.ndarray:
            return np.where(child >= 0, parent_of[np.maximum(child, 0)] if len(parent_of) else -1, -1)

        sample_i = self.resolve("sample_data", "sample_token", "sample")
        scene_of_sample = self.resolve("sample", "scene_token", "scene")
        scene_i = via(sample_i, scene_of_sample)
        log_i = via(scene_i, self.resolve("scene", "log_token", "log"))
        cs_i = self.resolve("sample_data", "calibrated_sensor_token", "calibrated_sensor")
        sensor_i = via(cs_i, self.resolve("calibrated_sensor", "sensor_token", "sensor"))
        channels = self.col("sensor", "channel", _S)
        chan_names = sorted({c for c in channels if c})
        chan_of_sensor = np.array([chan_names.index(c) if c else -1 for c in channels], dtype=np.int64)
        mod_of_sensor = np.array([MODALITIES.index(m) if m in MODALITIES else -1
                                  for m in self.col("sensor", "modality", _S)], dtype=np.int64)
        return {"sample": sample_i, "scene": scene_i, "log": log_i, "channel": via(sensor_i, chan_of_sensor),
                "modality": via(sensor_i, mod_of_sensor), "channel_names": np.array(chan_names, dtype=object),
                "scene_of_sample": scene_of_sample}
