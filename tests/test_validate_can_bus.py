"""``nuav2 validate`` checks the CAN bus pose files ``convert`` writes (validate_can_bus.py)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from e2e_helpers import VERSION

from nuav2.nuscenes_db.validate import validate_database

pytest_plugins = ["test_writer_support", "e2e_support"]


def _copy(db: Path, tmp_path: Path) -> Path:
    root = tmp_path / "db"
    shutil.copytree(db, root, symlinks=True)
    return root


def _problems(root: Path) -> list[str]:
    report = validate_database(root, VERSION, check_files=False, check_images=False)
    return [p.message for p in report.problems if p.check == "can_bus"]


def _pose_file(root: Path) -> Path:
    return sorted((root / "can_bus").glob("scene-*_pose.json"))[0]


def test_the_converted_can_bus_validates(native_synth_db: Path):
    assert _problems(native_synth_db) == []


@pytest.mark.parametrize("breakage, expected", [
    (lambda p: p.unlink(), "not found"),
    (lambda p: p.write_text("[{\"utime\": 1}]"), "field 'accel' must be 3 finite numbers"),
    (lambda p: p.write_text("{not json"), "cannot parse"),
    (lambda p: p.write_text(json.dumps(json.loads(p.read_text())[::-1])), "'utime' must increase"),
    (lambda p: p.write_text(json.dumps(json.loads(p.read_text())[3:])), "later than the scene's first"),
])
def test_a_broken_pose_file_is_named(native_synth_db: Path, tmp_path: Path, breakage, expected: str):
    root = _copy(native_synth_db, tmp_path)
    path = _pose_file(root)
    breakage(path)
    problems = _problems(root)
    assert len(problems) == 1 and expected in problems[0] and path.name in problems[0], problems


def test_a_missing_folder_is_a_problem_only_for_a_nuav2_conversion(native_synth_db: Path, tmp_path: Path):
    root = _copy(native_synth_db, tmp_path)
    shutil.rmtree(root / "can_bus")
    assert len(_problems(root)) == 1 and "not found" in _problems(root)[0]
    (root / VERSION / "nuav2_logs.json").unlink()  # any nuScenes-format database: the expansion is optional
    assert _problems(root) == []
