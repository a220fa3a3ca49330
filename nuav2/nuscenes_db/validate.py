"""Conformance checker for a nuScenes database (tables, linked lists, files, map expansion).

Why: the devkit fails late and vaguely (a KeyError deep in reverse indexing) or not at all
(MapTR silently drops invalid polygons and lanes without arclines). This names the table, the
token, the field and what is wrong, and never raises on bad data. Checks are columnar (numpy
over token indexes) so a 150-log database (~1M sample_data rows) validates in seconds plus the
file scan. A record whose own fields are broken is reported once and left out of the checks
that depend on it, so one defect does not cascade into many reports.
"""

from __future__ import annotations

import contextlib
import gc
import itertools
import json
import os
import re
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nuav2.nuscenes_db.validate_map import devkit_load_maps, validate_map_expansion
from nuav2.progress import progress_bar

TABLES = ("category", "attribute", "visibility", "instance", "sensor", "calibrated_sensor", "ego_pose",
          "log", "scene", "sample", "sample_data", "sample_annotation", "map")
MODALITIES = ("camera", "lidar", "radar")
SCENE_NAME_RE = re.compile(r"^scene-\d{4}$")  # NuScenesCanBus asserts it
QUAT_TOL = 1e-6
LIDAR_ROW_BYTES = 5 * 4  # x, y, z, intensity, ring as float32
DEFAULT_MAX_PER_KIND = 20

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


@dataclass(frozen=True)
class Problem:
    """One conformance failure: where (table, record token, field) and what is wrong."""

    table: str
    token: str
    field: str
    message: str
    check: str = ""  # kind of check, e.g. "foreign_key"; the cap counts per (table, field, check)


@dataclass
class ValidationReport:
    """Problems found (capped per kind) plus the true count of each kind and the table sizes."""

    dataroot: Path
    version: str
    max_per_kind: int = DEFAULT_MAX_PER_KIND
    problems: list[Problem] = field(default_factory=list)
    kind_counts: Counter = field(default_factory=Counter)
    table_counts: dict[str, int] = field(default_factory=dict)

    def add(self, table: str, token: str, field_: str, message: str, check: str) -> None:
        kind = (table, field_, check)
        self.kind_counts[kind] += 1
        if self.kind_counts[kind] <= self.max_per_kind:
            self.problems.append(Problem(table, token, field_, message, check))

    @property
    def ok(self) -> bool:
        return not self.kind_counts

    @property
    def n_problems(self) -> int:
        """All problems found, including those beyond the per-kind cap."""
        return sum(self.kind_counts.values())

    def suppressed(self) -> dict[tuple[str, str, str], int]:
        """(table, field, check) -> how many problems of that kind were counted but not kept."""
        return {k: n - self.max_per_kind for k, n in self.kind_counts.items() if n > self.max_per_kind}

    def format_text(self) -> str:
        """Problems grouped by table, or a one-line OK with the row count of every table."""
        if self.ok:
            counts = ", ".join(f"{t} {n}" for t, n in self.table_counts.items())
            return f"OK: {self.dataroot} version {self.version} conforms ({counts})"
        lines = [f"FAIL: {self.dataroot} version {self.version}: {self.n_problems} problem(s)"]
        hidden = self.suppressed()
        for table in dict.fromkeys(t for t, _, _ in self.kind_counts):
            n_table = sum(n for (t, _, _), n in self.kind_counts.items() if t == table)
            lines.append(f"[{table or 'database'}] {n_table} problem(s)")
            for p in (p for p in self.problems if p.table == table):
                where = " ".join(s for s in (p.token, p.field) if s)
                lines.append(f"  {p.check}: {where + ': ' if where else ''}{p.message}")
            for (t, f, c), n in hidden.items():
                if t == table:
                    lines.append(f"  {c}: ... and {n} more {f or 'record'} problem(s) of this kind")
        return "\n".join(lines)

    def to_json(self) -> dict:
        return {"dataroot": str(self.dataroot), "version": self.version, "ok": self.ok,
                "n_problems": self.n_problems, "table_counts": self.table_counts,
                "problems": [vars(p) for p in self.problems],
                "suppressed": [{"table": t, "field": f, "check": c, "count": n}
                               for (t, f, c), n in self.suppressed().items()]}


def validate_database(dataroot: str | Path, version: str, *, check_files: bool = True,
                      check_images: bool = True, devkit: bool = False,
                      max_per_kind: int = DEFAULT_MAX_PER_KIND, progress: bool = False) -> ValidationReport:
    """Check ``dataroot/version`` against what nuscenes-devkit and MapTR need; never raises on bad data.

    ``check_files`` stats every sample_data file and map PNG; ``check_images`` also reads each
    image header; ``devkit`` finally instantiates ``NuScenes`` and ``NuScenesMap`` themselves.
    """
    report = ValidationReport(Path(dataroot), version, max_per_kind=max_per_kind)
    with _gc_paused():
        _Checker(Path(dataroot), version, report, progress).run(check_files, check_images, devkit)
    return report


@contextlib.contextmanager
def _gc_paused() -> Iterator[None]:
    """Millions of acyclic JSON records make each cyclic-GC pass walk them all: pause it meanwhile."""
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was_enabled:
            gc.enable()


class _Checker:
    """Holds the loaded tables, their token indexes and cached columns while checks run."""

    def __init__(self, dataroot: Path, version: str, report: ValidationReport, progress: bool):
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

    def run(self, check_files: bool, check_images: bool, devkit: bool) -> None:
        if not self.table_root.is_dir():
            self.add("", "", "", f"version directory not found: {self.table_root}", "layout")
            return
        for table in TABLES:
            self._load(table)
        steps: list[tuple[str, Callable[[], None]]] = [
            ("schema", self._check_schema), ("foreign keys", self._check_foreign_keys),
            ("sensors", self._check_sensors), ("poses", self._check_poses),
            ("annotations", self._check_annotation_values), ("scenes", self._check_scenes),
            ("sample list", self._check_sample_list), ("sample_data lists", self._check_sample_data_lists),
            ("annotation lists", self._check_annotation_lists), ("maps", self._check_map_table),
            ("splits", self._check_splits), ("optional tables", self._check_optional_tables),
            ("map expansion", self._check_map_expansions)]
        if check_files:
            steps.append(("files", lambda: self._check_files(check_images)))
        if devkit:
            steps.append(("devkit", self._check_devkit))
        for name, step in steps:
            try:
                step()
            except Exception as e:  # a checker bug must not hide what was already found: report it
                self.add("", "", "", f"{name} check crashed: {type(e).__name__}: {e}", "internal")

    # ------------------------------------------------------------ table access
    def _load(self, table: str) -> None:
        path = self.table_root / f"{table}.json"
        self.recs[table], self.index[table] = [], {}
        if not path.is_file():
            self.add(table, "", "", f"table file missing: {path}", "missing_table")
            return
        try:
            with open(path, "rb") as f:
                data = json.load(f)
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

    # ---------------------------------------------------------- record checks
    def _check_schema(self) -> None:
        for table, fields in SCHEMA.items():
            recs, tokens = self.recs[table], self.tokens(table)
            for name, kind in fields.items():
                col = self.col(table, name, kind)
                for i in (i for i, v in enumerate(col) if v is None) if None in col else ():
                    v = recs[i].get(name, _MISSING)
                    msg = "missing field" if v is _MISSING else \
                        f"must be {_TYPE_WORD[kind]}, got {type(v).__name__} {v!r:.60}"
                    self.add(table, tokens[i] or f"#{i}", name, msg, "schema")

    def _check_foreign_keys(self) -> None:
        for table, name, target in FOREIGN_KEYS:
            self._fk(table, name, target)
        for table in ("sample", "sample_data", "sample_annotation"):
            for name in ("prev", "next"):
                self._fk(table, name, table, allow_empty=True)
        for table, name, target in (("sample_annotation", "attribute_tokens", "attribute"),
                                    ("map", "log_tokens", "log")):
            if target not in self.usable:
                continue
            index, col = self.index[target], self.col(table, name, _L)
            flat = list(itertools.chain.from_iterable(v for v in col if v is not None))
            if set(map(type, flat)) <= {str} and not set(flat) - index.keys():
                continue
            tokens = self.tokens(table)
            for i, lst in enumerate(col):
                for v in lst or ():
                    if not isinstance(v, str) or v not in index:
                        self.add(table, tokens[i], name, f"{v!r:.40} not found in {target}", "foreign_key")

    def _fk(self, table: str, name: str, target: str, *, allow_empty: bool = False) -> None:
        if target not in self.usable:
            return  # the target's own problem is reported; do not flood with dangling keys
        col, row = self.col(table, name, _S), self.resolve(table, name, target)
        bad = (row == -2) | (row == -1) if not allow_empty else row == -2
        if bad.any():
            tokens = self.tokens(table)
            for i in np.flatnonzero(bad):
                if col[i] is not None:  # None: wrong type, reported by the schema check
                    self.add(table, tokens[i], name, f"{col[i]!r} not found in {target}", "foreign_key")

    def _check_sensors(self) -> None:
        tokens = self.tokens("sensor")
        for i, m in enumerate(self.col("sensor", "modality", _S)):
            if m is not None and m not in MODALITIES:
                self.add("sensor", tokens[i], "modality", f"{m!r} is not one of {MODALITIES}", "value")
        for i, ch in enumerate(self.col("sensor", "channel", _S)):
            if ch == "":
                self.add("sensor", tokens[i], "channel", "empty channel name", "value")
        self._check_quaternions("calibrated_sensor")
        self.vectors("calibrated_sensor", "translation", 3)
        sensor_i = self.resolve("calibrated_sensor", "sensor_token", "sensor")
        modality = self.col("sensor", "modality", _S)
        tokens = self.tokens("calibrated_sensor")
        for i, K in enumerate(self.col("calibrated_sensor", "camera_intrinsic", _L)):
            m = modality[sensor_i[i]] if sensor_i[i] >= 0 else None
            if K is None or m not in MODALITIES:
                continue  # unreadable K or unknown modality: reported already
            msg = _intrinsic_problem(K) if m == "camera" else \
                None if K == [] else f"must be [] for a {m} sensor, got {K!r:.60}"
            if msg:
                self.add("calibrated_sensor", tokens[i], "camera_intrinsic", msg, "intrinsic")

    def _check_quaternions(self, table: str) -> None:
        q, finite = self.vectors(table, "rotation", 4)
        norm = np.linalg.norm(np.where(finite[:, None], q, 1.0), axis=1)
        tokens = self.tokens(table)
        for i in np.flatnonzero(np.abs(norm - 1.0) > QUAT_TOL):
            self.add(table, tokens[i], "rotation", f"not a unit quaternion: |q| = {norm[i]:.9f} "
                     f"(tolerance {QUAT_TOL:g})", "quaternion")

    def _check_poses(self) -> None:
        self._check_quaternions("ego_pose")
        t, finite = self.vectors("ego_pose", "translation", 3)
        tokens = self.tokens("ego_pose")
        for i in np.flatnonzero(finite & np.any(t[:, :2] < 0, axis=1)):
            self.add("ego_pose", tokens[i], "translation", f"negative global x/y {t[i, :2].tolist()}: the "
                     "map mask puts (0, 0) at its bottom-left", "coordinates")
        ts, ok = self.ints("ego_pose", "timestamp")
        for i in np.flatnonzero(ok & (ts < 0)):
            self.add("ego_pose", tokens[i], "timestamp", f"negative timestamp {ts[i]}", "value")

    def _check_annotation_values(self) -> None:
        table = "sample_annotation"
        tokens = self.tokens(table)
        self._check_quaternions(table)
        self.vectors(table, "translation", 3)
        size, finite = self.vectors(table, "size", 3)
        for i in np.flatnonzero(finite & np.any(size <= 0, axis=1)):
            self.add(table, tokens[i], "size", f"box size must be positive, got {size[i].tolist()}", "value")
        attrs = self.col(table, "attribute_tokens", _L)
        if not set(map(len, (a for a in attrs if a is not None))) <= {0, 1}:
            for i in (i for i, a in enumerate(attrs) if a is not None and len(a) > 1):
                self.add(table, tokens[i], "attribute_tokens", f"{len(attrs[i])} attributes: the detection "
                         "eval raises on more than one per box", "value")
        for name in ("num_lidar_pts", "num_radar_pts"):
            n, ok = self.ints(table, name)
            for i in np.flatnonzero(ok & (n < 0)):
                self.add(table, tokens[i], name, f"negative count {n[i]}", "value")

    def _check_scenes(self) -> None:
        tokens = self.tokens("scene")
        seen: dict[str, str] = {}
        for i, name in enumerate(self.col("scene", "name", _S)):
            if name is None:
                continue
            if not SCENE_NAME_RE.match(name):
                self.add("scene", tokens[i], "name", f"{name!r} is not 'scene-NNNN' (NuScenesCanBus asserts "
                         "^scene-\\d{4}$)", "scene_name")
            if name in seen:
                self.add("scene", tokens[i], "name", f"{name!r} is also the name of scene {seen[name]}",
                         "scene_name")
            seen.setdefault(name, tokens[i])
        if "sample" in self.usable:
            scene_i = self.resolve("sample", "scene_token", "scene")
            count = np.bincount(scene_i[scene_i >= 0], minlength=len(tokens))
            nbr, ok = self.ints("scene", "nbr_samples")
            for i in np.flatnonzero(ok & (nbr != count)):
                self.add("scene", tokens[i], "nbr_samples",
                         f"is {nbr[i]} but the scene has {count[i]} samples", "count")
        log_tokens = self.tokens("log")
        for i, loc in enumerate(self.col("log", "location", _S)):
            if loc == "":
                self.add("log", log_tokens[i], "location", "empty location", "value")

    # ------------------------------------------------------------ linked lists
    def _check_chain(self, table: str, group: np.ndarray, key: np.ndarray, key_ok: np.ndarray,
                     describe: Callable[[int], str], ends: Sequence[tuple] = ()) -> np.ndarray:
        """Check the doubly linked list of each group against the order of ``key`` (strictly increasing).

        ``group`` is -1 where a record's group is unknown and ``key_ok`` False where its key is
        (both reported elsewhere). ``ends`` lists (group, owner table, owner token, first field,
        first token, last field, last token). Returns the checked rows sorted by (group, key).
        """
        tokens = self.tokens(table)
        n = len(tokens)
        prev_i, next_i = self.resolve(table, "prev", table), self.resolve(table, "next", table)
        valid = (group >= 0) & key_ok
        partial = set(np.unique(group[(group >= 0) & ~key_ok]).tolist())  # groups with an unplaceable record
        rows = np.flatnonzero(valid)
        order = rows[np.lexsort((rows, key[rows], group[rows]))]
        g, k = group[order], key[order]
        same = g[1:] == g[:-1]
        dup = same & (k[1:] == k[:-1])
        for p in np.flatnonzero(dup):
            self.add(table, tokens[order[p + 1]], "timestamp", f"timestamp {k[p + 1]} equals that of "
                     f"{tokens[order[p]]} in {describe(g[p])}: not strictly increasing", "timestamp_order")
        skip = valid & np.isin(group, np.unique(g[1:][dup]))  # ambiguous order: duplicates reported above
        exp_next, exp_prev = np.full(n, -3), np.full(n, -3)
        if len(order):
            exp_next[order[:-1]], exp_next[order[-1]] = np.where(same, order[1:], -1), -1
            exp_prev[order[1:]], exp_prev[order[0]] = np.where(same, order[:-1], -1), -1
        for name, link, back, expected, later in (("next", next_i, prev_i, exp_next, True),
                                                  ("prev", prev_i, next_i, exp_prev, False)):
            for i in np.flatnonzero(valid & ~skip & (link != expected) & (link != -2)):
                msg = _link_message(name, i, int(link[i]), int(expected[i]), back, group, key, valid, tokens,
                                    describe, later)
                if msg:
                    self.add(table, tokens[i], name, msg, "linked_list")
        starts = np.flatnonzero(np.r_[True, ~same]) if len(order) else np.zeros(0, dtype=np.int64)
        stops = np.r_[starts[1:] - 1, len(order) - 1] if len(order) else starts
        head = dict(zip(g[starts].tolist(), order[starts].tolist()))
        tail = dict(zip(g[stops].tolist(), order[stops].tolist()))
        for gid, owner, owner_tok, first_field, first_tok, last_field, last_tok in ends:
            if gid in partial:
                continue
            if gid not in head:
                self.add(owner, owner_tok, first_field, f"{describe(gid)} has no {table} records",
                         "linked_list")
                continue
            for fld, have, want, which in ((first_field, first_tok, head[gid], "earliest"),
                                           (last_field, last_tok, tail[gid], "latest")):
                if have is not None and have != tokens[want]:
                    self.add(owner, owner_tok, fld, f"is {have!r} but the {which} {table} of {describe(gid)} "
                             f"is {tokens[want]}", "linked_list")
        return order

    def _check_sample_list(self) -> None:
        scene_i = self.resolve("sample", "scene_token", "scene")
        ts, ok = self.ints("sample", "timestamp")
        names = self.col("scene", "name", _S, default="?")
        scene_tokens = self.tokens("scene")
        firsts = self.col("scene", "first_sample_token", _S)
        lasts = self.col("scene", "last_sample_token", _S)
        ends = [(i, "scene", scene_tokens[i], "first_sample_token", firsts[i], "last_sample_token", lasts[i])
                for i in range(len(scene_tokens))]
        self._check_chain("sample", scene_i, ts, ok, lambda g: f"scene {names[g]}", ends)

    def _check_annotation_lists(self) -> None:
        table = "sample_annotation"
        inst_i = self.resolve(table, "instance_token", "instance")
        sample_i = self.resolve(table, "sample_token", "sample")
        sample_ts, ts_ok = self.ints("sample", "timestamp")
        at = np.maximum(sample_i, 0)
        key_ok = (sample_i >= 0) & (ts_ok[at] if len(ts_ok) else False)
        key = np.where(key_ok, sample_ts[at] if len(sample_ts) else 0, 0)
        inst_tokens = self.tokens("instance")
        firsts = self.col("instance", "first_annotation_token", _S)
        lasts = self.col("instance", "last_annotation_token", _S)
        ends = [(i, "instance", t, "first_annotation_token", firsts[i], "last_annotation_token", lasts[i])
                for i, t in enumerate(inst_tokens)]
        self._check_chain(table, inst_i, key, key_ok, lambda g: f"instance {inst_tokens[g]}", ends)
        count = np.bincount(inst_i[inst_i >= 0], minlength=len(inst_tokens))
        nbr, ok = self.ints("instance", "nbr_annotations")
        for i in np.flatnonzero(ok & (nbr != count)):
            self.add("instance", inst_tokens[i], "nbr_annotations",
                     f"is {nbr[i]} but the instance has {count[i]} annotations", "count")

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

    def _check_sample_data_lists(self) -> None:
        table = "sample_data"
        cols = self._sample_data_columns()
        tokens = self.tokens(table)
        chan_names = cols["channel_names"]
        n_ch = max(len(chan_names), 1)
        ts, ok = self.ints(table, "timestamp")
        known = (cols["scene"] >= 0) & (cols["channel"] >= 0)
        group = np.where(known, cols["scene"] * n_ch + cols["channel"], -1)
        scene_names = self.col("scene", "name", _S, default="?")
        order = self._check_chain(table, group, ts, ok,
                                  lambda g: f"scene {scene_names[g // n_ch]} channel {chan_names[g % n_ch]}")
        is_kf, kf_known = self.bools(table, "is_key_frame")
        self._check_key_frames(cols, is_kf, kf_known, ts, ok, tokens)
        self._check_sweep_samples(cols, order, group, is_kf, kf_known, ts, tokens)
        self._check_unique_timestamps(cols, ts, ok, tokens)

    def _check_key_frames(self, cols: dict, is_kf: np.ndarray, kf_known: np.ndarray, ts: np.ndarray,
                          ts_ok: np.ndarray, tokens: list[str]) -> None:
        """Each sample gets exactly one key frame per channel its scene records, LIDAR_TOP included."""
        chan_names = list(cols["channel_names"])
        n_ch, n_sample = max(len(chan_names), 1), len(self.recs["sample"])
        sample_tokens = self.tokens("sample")
        sample_i, chan_i = cols["sample"], cols["channel"]
        kf = is_kf & (sample_i >= 0) & (chan_i >= 0)
        count = np.bincount(sample_i[kf] * n_ch + chan_i[kf], minlength=n_sample * n_ch)
        count = count.reshape(n_sample, n_ch)
        for s, c in zip(*np.nonzero(count > 1)):
            self.add("sample", sample_tokens[s], "data", f"{count[s, c]} key-frame sample_data for channel "
                     f"{chan_names[c]} (the devkit keeps the last)", "key_frame")
        # a sample with a row of unknown channel or key-frame flag cannot be judged incomplete
        unsure = np.zeros(n_sample, dtype=bool)
        unsure[sample_i[(sample_i >= 0) & ((chan_i < 0) | ~kf_known)]] = True
        scene_of = cols["scene_of_sample"]
        n_scene = len(self.recs["scene"])
        scene_row = np.where(scene_of >= 0, scene_of, n_scene)  # extra row: samples of unknown scene
        scene_has = np.zeros((n_scene + 1, n_ch), dtype=bool)
        np.logical_or.at(scene_has, scene_row, count > 0)
        missing = scene_has[scene_row] & (count == 0) & ~unsure[:, None] & (scene_of >= 0)[:, None]
        for s, c in zip(*np.nonzero(missing)):
            self.add("sample", sample_tokens[s], "data", f"no key-frame sample_data for channel "
                     f"{chan_names[c]}, which its scene records", "key_frame")
        if "LIDAR_TOP" not in chan_names:
            if n_sample and len(tokens) and "sensor" in self.usable:
                self.add("sensor", "", "channel", f"no LIDAR_TOP sample_data at all {LIDAR_NEEDED}",
                         "key_frame")
            return
        lidar = chan_names.index("LIDAR_TOP")
        for s in np.flatnonzero((count[:, lidar] == 0) & ~missing[:, lidar] & ~unsure):
            self.add("sample", sample_tokens[s], "data", f"no LIDAR_TOP key frame {LIDAR_NEEDED}",
                     "key_frame")
        sample_ts, s_ok = self.ints("sample", "timestamp")
        rows = np.flatnonzero(kf & (chan_i == lidar) & ts_ok)
        s_of = sample_i[rows]
        differs = s_ok[s_of] & (sample_ts[s_of] != ts[rows])
        for r, s in zip(rows[differs], s_of[differs]):
            self.add("sample", sample_tokens[s], "timestamp", f"{sample_ts[s]} differs from that of its "
                     f"LIDAR_TOP key frame {tokens[r]} ({ts[r]})", "key_frame")

    def _check_sweep_samples(self, cols: dict, order: np.ndarray, group: np.ndarray, is_kf: np.ndarray,
                             kf_known: np.ndarray, ts: np.ndarray, tokens: list[str]) -> None:
        """A sweep belongs to the sample that follows it: the sample of its channel's next key frame, or
        the first sample of its scene at or after its timestamp (either reading of the format is fine;
        past the end, the last one)."""
        if not len(order):
            return
        g, kf, n = group[order], is_kf[order], len(order)
        pos = np.arange(n)
        nxt = np.minimum.accumulate(np.where(kf, pos, n)[::-1])[::-1]
        prv = np.maximum.accumulate(np.where(kf, pos, -1))
        nxt_ok = (nxt < n) & (g[np.minimum(nxt, n - 1)] == g)
        prv_ok = (prv >= 0) & (g[np.maximum(prv, 0)] == g)
        ref = np.where(nxt_ok, nxt, np.where(prv_ok, prv, -1))
        sample_i = cols["sample"]
        expected = np.where(ref >= 0, sample_i[order[np.maximum(ref, 0)]], -1)
        unsure = np.isin(g, np.unique(group[~kf_known]))
        suspects = np.flatnonzero(~kf & ~unsure & (expected >= 0) & (sample_i[order] != expected))
        if not len(suspects):
            return
        by_time = self._following_samples(cols, cols["scene"][order[suspects]], ts[order[suspects]])
        sample_tokens = self.tokens("sample")
        for p, alt in zip(suspects, by_time):
            r = order[p]
            if alt == sample_i[r]:
                continue
            which = "next" if nxt_ok[p] else "last"
            by_time = sample_tokens[alt] if alt >= 0 else "none"
            self.add("sample_data", tokens[r], "sample_token", f"sweep points at sample "
                     f"{sample_tokens[sample_i[r]]} but the {which} key frame of its channel "
                     f"({tokens[order[ref[p]]]}) belongs to sample {sample_tokens[expected[p]]} and the "
                     f"first sample at or after its timestamp is {by_time}", "sweep_sample")

    def _following_samples(self, cols: dict, scenes: np.ndarray, ts: np.ndarray) -> np.ndarray:
        """Per (scene, timestamp): the scene's first sample at or after it, else its last (-1: none)."""
        scene_of = cols["scene_of_sample"]
        sample_ts, ok = self.ints("sample", "timestamp")
        out = np.full(len(ts), -1, dtype=np.int64)
        for sc in np.unique(scenes):
            rows = np.flatnonzero((scene_of == sc) & ok)
            if len(rows):
                rows = rows[np.argsort(sample_ts[rows], kind="stable")]
                at = scenes == sc
                out[at] = rows[np.minimum(np.searchsorted(sample_ts[rows], ts[at]), len(rows) - 1)]
        return out

    def _check_unique_timestamps(self, cols: dict, ts: np.ndarray, ok: np.ndarray, tokens: list[str]) -> None:
        """No two sample_data of one channel in one log share a timestamp (across its scenes too)."""
        rows = np.flatnonzero(ok & (cols["log"] >= 0) & (cols["channel"] >= 0))
        rows = rows[np.lexsort((ts[rows], cols["channel"][rows], cols["log"][rows]))]
        log, ch, scene, t = cols["log"][rows], cols["channel"][rows], cols["scene"][rows], ts[rows]
        dup = (log[1:] == log[:-1]) & (ch[1:] == ch[:-1]) & (t[1:] == t[:-1]) & (scene[1:] != scene[:-1])
        for p in np.flatnonzero(dup):  # same-scene duplicates are reported by the linked-list check
            self.add("sample_data", tokens[rows[p + 1]], "timestamp", f"timestamp {t[p + 1]} of channel "
                     f"{cols['channel_names'][ch[p]]} is also used by {tokens[rows[p]]} in another scene of "
                     "the same log", "timestamp_order")

    # ------------------------------------------------------------ map / splits
    def _check_map_table(self) -> None:
        if "map" in self.usable and not self.recs["map"]:
            self.add("map", "", "", "map table is empty (the devkit reads map[0]['log_tokens'])", "map_table")
        if "map" not in self.usable:
            return
        covered = {t for lst in self.col("map", "log_tokens", _L) for t in lst or () if isinstance(t, str)}
        for tok in self.tokens("log"):
            if tok and tok not in covered:
                self.add("log", tok, "token", "log is in no map record's log_tokens (NuScenes() raises "
                         "KeyError)", "map_table")

    def _check_splits(self) -> None:
        path = self.table_root / "splits.json"
        if not path.exists():
            return
        try:
            splits = json.loads(path.read_bytes())
        except (OSError, ValueError) as e:
            self.add("splits", "", "", f"cannot parse {path}: {e}", "bad_json")
            return
        if not isinstance(splits, dict):
            self.add("splits", "", "", f"{path} must map split name -> list of scene names", "splits")
            return
        names = set(self.col("scene", "name", _S, default=""))
        for split, scenes in splits.items():
            if not isinstance(scenes, list):
                self.add("splits", split, "", "must be a list of scene names", "splits")
                continue
            for s in scenes:
                if not isinstance(s, str) or s not in names:
                    self.add("splits", split, "", f"scene {s!r} is not in the scene table", "splits")

    def _check_optional_tables(self) -> None:
        """lidarseg/panoptic make the devkit demand category['index']."""
        tasks = [t for t in ("lidarseg", "panoptic") if (self.table_root / f"{t}.json").exists()]
        tokens = self.tokens("category")
        for i, r in enumerate(self.recs["category"] if tasks else ()):
            if "index" not in r:
                self.add("category", tokens[i], "index", f"missing; needed because {tasks[0]}.json exists",
                         "schema")

    def _locations(self) -> list[str]:
        return sorted({v for v in self.col("log", "location", _S) if v})

    def _check_map_expansions(self) -> None:
        for loc in self._locations():
            validate_map_expansion(self.dataroot / "maps" / "expansion" / f"{loc}.json", loc, self.add)

    # ------------------------------------------------------------------ files
    def _check_files(self, check_images: bool) -> None:
        tokens = self.tokens("map")
        for i, rel in enumerate(self.col("map", "filename", _S)):
            msg = None if rel is None else _relpath_problem(rel) or _png_problem(self.dataroot / rel)
            if msg:
                self.add("map", tokens[i], "filename", msg, "file")
        table = "sample_data"
        tokens = self.tokens(table)
        names = self.col(table, "filename", _S)
        (widths, w_ok), (heights, h_ok) = self.ints(table, "width"), self.ints(table, "height")
        modality = self._sample_data_columns()["modality"]
        cam, lidar = MODALITIES.index("camera"), MODALITIES.index("lidar")
        listing: dict[str, dict[str, os.DirEntry]] = {}
        for i in progress_bar(range(len(names)), desc="sample_data files", unit="file",
                              disable=not self.progress, mininterval=1.0):
            rel = names[i]
            if rel is None:
                continue
            bad = _relpath_problem(rel)
            if bad:
                self.add(table, tokens[i], "filename", bad, "file")
                continue
            folder, base = os.path.split(rel)
            if folder not in listing:
                listing[folder] = _scan(self.dataroot / folder)
            entry = listing[folder].get(base)
            if entry is None:
                self.add(table, tokens[i], "filename", f"file not found: {self.dataroot / rel}",
                         "missing_file")
            elif modality[i] == lidar:
                self._check_lidar_file(tokens[i], rel, entry)
            elif modality[i] == cam and w_ok[i] and h_ok[i]:
                if widths[i] <= 0 or heights[i] <= 0:
                    self.add(table, tokens[i], "width", f"camera image size {widths[i]}x{heights[i]} is not "
                             "positive", "image_size")
                if check_images:
                    self._check_image(tokens[i], rel, (int(widths[i]), int(heights[i])))

    def _check_lidar_file(self, token: str, rel: str, entry: os.DirEntry) -> None:
        if not rel.endswith(".bin"):
            self.add("sample_data", token, "filename", f"{rel}: a lidar file must end in .bin "
                     "(LidarPointCloud asserts it)", "lidar_file")
        size = entry.stat().st_size
        if size == 0 or size % LIDAR_ROW_BYTES:
            self.add("sample_data", token, "filename", f"{rel}: {size} bytes is not a positive multiple of "
                     f"{LIDAR_ROW_BYTES} (5 float32 per point)", "lidar_file")

    def _check_image(self, token: str, rel: str, wh: tuple[int, int]) -> None:
        size = image_size(self.dataroot / rel)
        if isinstance(size, str):
            self.add("sample_data", token, "filename", f"{rel}: {size}", "image_file")
        elif size != wh:
            self.add("sample_data", token, "width", f"width x height {wh[0]}x{wh[1]} but the image header of "
                     f"{rel} says {size[0]}x{size[1]}", "image_size")

    def _check_devkit(self) -> None:
        """Instantiate the real devkit classes: the final word on whether the database loads."""
        from nuscenes.nuscenes import NuScenes  # heavy import: only when asked

        try:
            NuScenes(version=self.version, dataroot=str(self.dataroot), verbose=False)
        except Exception as e:
            self.add("devkit", "", "", f"NuScenes(version={self.version!r}) raised {type(e).__name__}: {e}",
                     "devkit")
        devkit_load_maps(self.dataroot, self._locations(), self.add)


_MISSING = object()


def _link_message(name: str, i: int, j: int, e: int, back: np.ndarray, group: np.ndarray, key: np.ndarray,
                  valid: np.ndarray, tokens: list[str], describe: Callable[[int], str],
                  later: bool) -> str | None:
    """Why record ``i``'s ``name`` link is ``j``, not the expected ``e``: one clause per failure mode."""
    if j == -1:
        return f"is empty but {tokens[e]} {'follows' if later else 'precedes'} it in {describe(group[i])}"
    if not valid[j]:
        return None  # the target cannot be placed; its own problem is reported
    if group[j] != group[i]:
        return f"{tokens[j]} belongs to {describe(group[j])}, not {describe(group[i])}"
    if (key[j] <= key[i]) if later else (key[j] >= key[i]):
        return (f"{tokens[j]} is not {'later' if later else 'earlier'} (timestamp {key[j]} "
                f"{'<=' if later else '>='} {key[i]}): cycle or out-of-order list")
    if back[j] != i:
        other = "prev" if name == "next" else "next"
        have = tokens[back[j]] if back[j] >= 0 else ""
        return f"prev/next not symmetric: {name} is {tokens[j]} but its {other} is {have!r}"
    if e >= 0:
        return f"is {tokens[j]} but {tokens[e]} lies between them in time"
    return f"is {tokens[j]} but the record is the {'last' if later else 'first'} of {describe(group[i])}"


def _intrinsic_problem(K: list) -> str | None:
    if len(K) != 3 or not all(isinstance(r, list) and len(r) == 3 for r in K) or \
            not all(type(x) in (int, float) for r in K for x in r):
        return f"must be a 3x3 list of numbers for a camera, got {K!r:.80}"
    arr = np.asarray(K, dtype=np.float64)
    if not np.all(np.isfinite(arr)):
        return f"contains NaN or Inf: {K}"
    if arr[0, 0] <= 0 or arr[1, 1] <= 0:
        return f"focal lengths must be positive, got fx={arr[0, 0]} fy={arr[1, 1]}"
    if arr[1, 0] != 0 or arr[2].tolist() != [0.0, 0.0, 1.0]:
        return f"must be upper triangular with last row [0, 0, 1], got {K}"
    return None


def _relpath_problem(rel: str) -> str | None:
    if not rel or os.path.isabs(rel) or ".." in Path(rel).parts:
        return f"filename {rel!r} must be a non-empty path relative to dataroot"
    return None


def _scan(folder: Path) -> dict[str, os.DirEntry]:
    """One listing per folder instead of one stat per file (1M files stat slowly on network disks)."""
    try:
        with os.scandir(folder) as it:
            return {e.name: e for e in it}
    except OSError:
        return {}


def _png_problem(path: Path) -> str | None:
    try:
        with open(path, "rb") as f:
            head = f.read(24)
    except OSError as e:
        return f"map mask not readable: {path} ({e.strerror or e})"
    if head[:8] != b"\x89PNG\r\n\x1a\n" or head[12:16] != b"IHDR":
        return f"map mask {path} is not a PNG"
    if int.from_bytes(head[16:20], "big") == 0 or int.from_bytes(head[20:24], "big") == 0:
        return f"map mask {path} has zero width or height"
    return None


_SOF_MARKERS = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}  # not DHT, JPG, DAC
_STANDALONE_MARKERS = frozenset([0x01, *range(0xD0, 0xD8)])  # TEM, RSTn: no length field


def image_size(path: str | Path) -> tuple[int, int] | str:
    """(width, height) from a JPEG's SOF (or a PNG's IHDR) header without decoding; else what is wrong."""
    try:
        with open(path, "rb") as f:
            head = f.read(2)
            if head == b"\x89P":
                rest = f.read(22)
                if rest[:6] != b"NG\r\n\x1a\n" or rest[10:14] != b"IHDR":
                    return "not a PNG (bad signature)"
                return int.from_bytes(rest[14:18], "big"), int.from_bytes(rest[18:22], "big")
            if head != b"\xff\xd8":
                return "not a JPEG (no SOI marker)"
            while True:
                byte = f.read(1)
                if byte != b"\xff":
                    return "truncated JPEG: no SOF header" if not byte else "corrupt JPEG: expected a marker"
                marker = f.read(1)
                while marker == b"\xff":  # fill bytes
                    marker = f.read(1)
                if not marker:
                    return "truncated JPEG: no SOF header"
                if marker[0] in _STANDALONE_MARKERS:
                    continue
                if marker[0] in (0xD9, 0xDA):
                    return "corrupt JPEG: image data before any SOF header"
                seg = f.read(2)
                if len(seg) < 2 or int.from_bytes(seg, "big") < 2:
                    return "truncated or corrupt JPEG segment header"
                if marker[0] in _SOF_MARKERS:
                    sof = f.read(5)  # precision, height, width
                    if len(sof) < 5:
                        return "truncated JPEG SOF header"
                    return int.from_bytes(sof[3:5], "big"), int.from_bytes(sof[1:3], "big")
                f.seek(int.from_bytes(seg, "big") - 2, os.SEEK_CUR)
    except OSError as e:
        return f"not readable ({e.strerror or e})"
