"""Validation of the CAN bus expansion's pose files (``<dataroot>/can_bus/scene-NNNN_pose.json``).

Why: BEVFormer's and MapTR's converters read these with a bare ``except`` around the read, so a
missing or broken file silently gives a sample an all-zero ``can_bus``. A nuAV2 conversion (its
version folder holds ``nuav2_logs.json``) writes one per scene, so there a missing file is a
problem; for other databases the expansion is a separate download that lacks some scenes, so only
the files that exist are checked.
"""

from __future__ import annotations

import math
from collections import defaultdict
from pathlib import Path

from nuav2.nuscenes_db.can_bus import CAN_BUS_DIRNAME
from nuav2.nuscenes_db.validate_tables import _S, TableStore, read_json

POSE_FIELDS = {"accel": 3, "orientation": 4, "pos": 3, "rotation_rate": 3, "vel": 3}


def pose_file_problem(path: Path, sample_times_us: list[int]) -> str | None:
    """What is wrong with one scene's pose file, or None."""
    try:
        messages = read_json(path)
    except (OSError, ValueError) as e:
        return f"cannot parse {path}: {e}"
    if not isinstance(messages, list) or not messages:
        return f"{path}: must be a non-empty list of pose messages"
    last = None
    for k, m in enumerate(messages):
        if not isinstance(m, dict) or not isinstance(m.get("utime"), int) or isinstance(m.get("utime"), bool):
            return f"{path}: message {k} needs an integer 'utime'"
        for name, n in POSE_FIELDS.items():
            v = m.get(name)
            if not (isinstance(v, list) and len(v) == n and all(
                    isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in v)):
                return f"{path}: message {k} field '{name}' must be {n} finite numbers"
        if last is not None and m["utime"] <= last:
            return f"{path}: 'utime' must increase (message {k}: {m['utime']} after {last})"
        last = m["utime"]
    if sample_times_us and messages[0]["utime"] > min(sample_times_us):
        return (f"{path}: the first message ({messages[0]['utime']}) is later than the scene's first sample "
                f"({min(sample_times_us)}): its can_bus would come from a later pose")
    return None


class CanBusChecks(TableStore):
    """The CAN bus expansion next to the tables."""

    def _check_can_bus(self) -> None:
        folder = self.dataroot / CAN_BUS_DIRNAME
        converted = (self.table_root / "nuav2_logs.json").is_file()
        if not folder.is_dir():
            if converted:
                self.add("scene", "", "", f"{folder} not found: nuav2 convert writes each scene's CAN bus "
                         "pose messages there (convert again to restore it)", "can_bus")
            return
        times: dict[str, list[int]] = defaultdict(list)
        stamps, ok = self.ints("sample", "timestamp")
        for scene, t, good in zip(self.col("sample", "scene_token", _S), stamps, ok):
            if scene is not None and good:
                times[scene].append(int(t))
        for token, name in zip(self.tokens("scene"), self.col("scene", "name", _S)):
            if not name:
                continue
            path = folder / f"{name}_pose.json"
            if not path.exists():
                if converted:
                    self.add("scene", token, "name", f"{path} not found", "can_bus")
                continue
            problem = pose_file_problem(path, times.get(token, []))
            if problem:
                self.add("scene", token, "name", problem, "can_bus")
