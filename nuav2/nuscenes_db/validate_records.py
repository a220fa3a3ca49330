"""Record-level checks: field types, foreign keys, sensors, poses, annotations, scenes, map table, splits."""

from __future__ import annotations

import itertools

import numpy as np

from nuav2.nuscenes_db.validate_tables import (
    _L,
    _S,
    _TYPE_WORD,
    FOREIGN_KEYS,
    MODALITIES,
    QUAT_TOL,
    SCENE_NAME_RE,
    SCHEMA,
    TableStore,
    read_json,
)

_MISSING = object()


class RecordChecks(TableStore):
    """Checks of single records and of the small tables (map, splits)."""

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
        q, finite = self.vectors(table, "rotation", 4)  # wrong shape or NaN/Inf: reported there, not here
        norm = np.linalg.norm(np.where(finite[:, None], q, 0.0), axis=1)
        tokens = self.tokens(table)
        for i in np.flatnonzero(finite & (np.abs(norm - 1.0) > QUAT_TOL)):
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
            splits = read_json(path)
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
