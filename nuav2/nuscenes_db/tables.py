"""The 13 nuScenes tables: their names, and the vocabularies shared by every log.

Per-log records (ego poses, samples, annotations, ...) are built in ``records.py`` by the
writer; the merge step concatenates them and adds the shared tables built here.
"""

from __future__ import annotations

from nuav2.nuscenes_db.categories import NUSCENES_ATTRIBUTES, NUSCENES_CATEGORIES, NUSCENES_VISIBILITY
from nuav2.nuscenes_db.tokens import global_token

# The order NuScenes() loads them in; all 13 must exist for the devkit to load a database.
TABLE_NAMES: tuple[str, ...] = (
    "category", "attribute", "visibility", "instance", "sensor", "calibrated_sensor", "ego_pose",
    "log", "scene", "sample", "sample_data", "sample_annotation", "map",
)
SHARED_TABLES: tuple[str, ...] = ("category", "attribute", "visibility", "sensor")
PER_LOG_TABLES: tuple[str, ...] = tuple(t for t in TABLE_NAMES if t not in SHARED_TABLES)


def category_token(name: str) -> str:
    return global_token("category", name)


def attribute_token(name: str) -> str:
    return global_token("attribute", name)


def sensor_token(channel: str) -> str:
    return global_token("sensor", channel)


def category_table() -> list[dict]:
    """All 23 nuScenes categories, sorted by name. No lidarseg ``index``: we write no lidarseg labels."""
    return [{"token": category_token(name), "name": name, "description": desc}
            for name, desc in sorted(NUSCENES_CATEGORIES.items())]


def attribute_table() -> list[dict]:
    return [{"token": attribute_token(name), "name": name, "description": desc}
            for name, desc in sorted(NUSCENES_ATTRIBUTES.items())]


def visibility_table() -> list[dict]:
    return [{"token": tok, "level": level, "description": desc} for tok, level, desc in NUSCENES_VISIBILITY]


def sensor_table(channels: dict[str, str]) -> list[dict]:
    """One sensor per channel name (``{channel: modality}``), sorted by channel."""
    bad = {ch: m for ch, m in channels.items() if m not in ("camera", "lidar", "radar")}
    if bad:
        raise ValueError(f"sensor modality must be camera/lidar/radar, got {bad}")
    return [{"token": sensor_token(ch), "channel": ch, "modality": channels[ch]} for ch in sorted(channels)]
