"""``nuav2 validate`` reads every JSON file as the devkit does, and never double-reports a rotation.

Built on a real converted database (``native_synth_db``): the devkit opens tables and map expansions as
UTF-8 text, so a byte-order mark or UTF-16 is unreadable there and must be a ``bad_json`` problem here;
a table nested too deeply for the parser is a problem too, not an internal error.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path

import pytest
from e2e_helpers import VERSION

from nuav2.nuscenes_db.validate import validate_database

pytest_plugins = ["test_writer_support", "e2e_support"]

BOM = b"\xef\xbb\xbf"


def _copy(db: Path, tmp_path: Path) -> Path:
    root = tmp_path / "db"
    shutil.copytree(db, root, symlinks=True)
    return root


def _validate(root: Path):
    return validate_database(root, VERSION, check_files=False, check_images=False)


def _with_bom(path: Path) -> None:
    path.write_bytes(BOM + path.read_bytes())


def _as_utf16(path: Path) -> None:
    path.write_text(path.read_text(encoding="utf-8"), encoding="utf-16")


def _deeply_nested(path: Path) -> None:
    path.write_text("[" * 100_000 + "]" * 100_000)


def _table(name: str) -> Callable[[Path], Path]:
    return lambda root: root / VERSION / f"{name}.json"


def _expansion(root: Path) -> Path:
    return sorted((root / "maps" / "expansion").glob("*.json"))[0]


def _pose_file(root: Path) -> Path:
    return sorted((root / "can_bus").glob("scene-*_pose.json"))[0]


@pytest.mark.parametrize("where, breakage, check, expected", [
    (_table("scene"), _with_bom, "bad_json", "Unexpected UTF-8 BOM"),
    (_table("sensor"), _as_utf16, "bad_json", "'utf-8' codec can't decode"),
    (_table("splits"), _with_bom, "bad_json", "Unexpected UTF-8 BOM"),
    (_expansion, _with_bom, "bad_json", "Unexpected UTF-8 BOM"),
    (_pose_file, _with_bom, "can_bus", "Unexpected UTF-8 BOM"),
    (_table("sample"), _deeply_nested, "bad_json", "nested too deeply"),
], ids=["bom_table", "utf16_table", "bom_splits", "bom_map_expansion", "bom_can_bus", "deep_nesting"])
def test_json_the_devkit_cannot_read_is_bad_json(native_synth_db: Path, tmp_path: Path,
                                                 where, breakage, check: str, expected: str) -> None:
    root = _copy(native_synth_db, tmp_path)
    path = where(root)
    assert path.is_file()
    breakage(path)
    report = _validate(root)
    hits = [p for p in report.problems if p.check == check and path.name in p.message]
    assert len(hits) == 1 and "cannot parse" in hits[0].message and expected in hits[0].message, \
        report.problems
    assert not [p for p in report.problems if p.check == "internal"], report.problems


def test_a_malformed_rotation_is_not_also_a_non_unit_quaternion(native_synth_db: Path,
                                                                tmp_path: Path) -> None:
    root = _copy(native_synth_db, tmp_path)
    path = root / VERSION / "calibrated_sensor.json"
    recs = json.loads(path.read_text())
    recs[0]["rotation"] = recs[0]["rotation"][:3]
    recs[1]["rotation"] = [float("nan"), 0.0, 0.0, 0.0]
    recs[2]["rotation"] = [1.0, 0.0, 0.0, 0.1]
    path.write_text(json.dumps(recs))
    found = {(p.token, p.check) for p in _validate(root).problems if p.table == "calibrated_sensor"}
    assert found == {(recs[0]["token"], "shape"), (recs[1]["token"], "non_finite"),
                     (recs[2]["token"], "quaternion")}, found
