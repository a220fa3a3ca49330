"""Conformance checker for a nuScenes database (tables, linked lists, files, map expansion).

Why: the devkit fails late and vaguely (a KeyError deep in reverse indexing) or not at all
(MapTR silently drops invalid polygons and lanes without arclines). This names the table, the
token, the field and what is wrong, and never raises on bad data. Checks are columnar (numpy
over token indexes) so a 150-log database (~1M sample_data rows) validates in seconds plus the
file scan. A record whose own fields are broken is reported once and left out of the checks
that depend on it, so one defect does not cascade into many reports.

By concern: ``validate_tables`` (loading, typed columns), ``validate_records`` (fields, keys,
values), ``validate_links`` (prev/next chains, key frames), ``validate_files`` (data files,
images), ``validate_map`` (map expansion JSON), ``validate_can_bus`` (CAN bus pose files),
``validate_report`` (the result).
"""

from __future__ import annotations

import contextlib
import gc
from collections.abc import Callable, Iterator
from pathlib import Path

from nuav2.nuscenes_db.validate_can_bus import CanBusChecks
from nuav2.nuscenes_db.validate_files import FileChecks, image_size
from nuav2.nuscenes_db.validate_links import LinkChecks
from nuav2.nuscenes_db.validate_map import devkit_load_maps, validate_map_expansion
from nuav2.nuscenes_db.validate_records import RecordChecks
from nuav2.nuscenes_db.validate_report import DEFAULT_MAX_PER_KIND, Problem, ValidationReport
from nuav2.nuscenes_db.validate_tables import _S, SCHEMA, TABLES

__all__ = ["DEFAULT_MAX_PER_KIND", "SCHEMA", "Problem", "ValidationReport", "image_size", "validate_database"]


def validate_database(dataroot: str | Path, version: str, *, check_files: bool = True,
                      check_images: bool = True, decode_images: bool = False, devkit: bool = False,
                      max_per_kind: int = DEFAULT_MAX_PER_KIND, progress: bool = False) -> ValidationReport:
    """Check ``dataroot/version`` against what nuscenes-devkit and MapTR need; never raises on bad data.

    ``check_files`` stats every sample_data file and map PNG; ``check_images`` also reads each
    image header; ``decode_images`` decodes every image to its end (finds truncated JPEGs, ~3 ms
    per AV2 image); ``devkit`` finally instantiates ``NuScenes`` and ``NuScenesMap`` themselves.
    """
    report = ValidationReport(Path(dataroot), version, max_per_kind=max_per_kind)
    with _gc_paused():
        _Checker(Path(dataroot), version, report, progress).run(check_files, check_images or decode_images,
                                                                devkit, decode_images)
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


class _Checker(RecordChecks, LinkChecks, FileChecks, CanBusChecks):
    """Runs every check over one database; a crashing check is reported, never raised."""

    def run(self, check_files: bool, check_images: bool, devkit: bool, decode_images: bool = False) -> None:
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
            ("map expansion", self._check_map_expansions), ("log placement", self._check_log_placement),
            ("CAN bus", self._check_can_bus)]
        if check_files:
            steps.append(("files", lambda: self._check_files(check_images, decode_images)))
        if devkit:
            steps.append(("devkit", self._check_devkit))
        for name, step in steps:
            try:
                step()
            except Exception as e:  # a checker bug must not hide what was already found: report it
                self.add("", "", "", f"{name} check crashed: {type(e).__name__}: {e}", "internal")

    def _locations(self) -> list[str]:
        return sorted({v for v in self.col("log", "location", _S) if v})

    def _check_map_expansions(self) -> None:
        for loc in self._locations():
            validate_map_expansion(self.dataroot / "maps" / "expansion" / f"{loc}.json", loc, self.add)

    def _check_log_placement(self) -> None:
        """In a nuAV2 conversion (``nuav2_logs.json`` present), each nuAV2 log's city and offset (there, else
        in its expansion's ``nuav2`` block), which ``nuav2 split`` needs to place scenes in true city
        coordinates; logs of other maps are skipped."""
        from nuav2.nuscenes_db.map_frame import LOCATION_RE
        from nuav2.nuscenes_db.merge import LOGS_FILE
        from nuav2.splits.database import log_city_placement

        if not (self.table_root / LOGS_FILE).is_file():
            return
        cache: dict = {}
        for token, location in zip(self.tokens("log"), self.col("log", "location", _S)):
            if not location or not LOCATION_RE.match(location):
                continue
            try:
                log_city_placement(self.dataroot, self.version, {"token": token, "location": location}, cache)
            except ValueError as e:
                self.add("log", token, "location", str(e), "placement")
                if "sidecar" not in cache:  # nuav2_logs.json itself is unreadable: once, not per log
                    return

    def _check_devkit(self) -> None:
        """Instantiate the real devkit classes: the final word on whether the database loads."""
        from nuscenes.nuscenes import NuScenes  # heavy import: only when asked

        try:
            NuScenes(version=self.version, dataroot=str(self.dataroot), verbose=False)
        except Exception as e:
            self.add("devkit", "", "", f"NuScenes(version={self.version!r}) raised {type(e).__name__}: {e}",
                     "devkit")
        devkit_load_maps(self.dataroot, self._locations(), self.add)
