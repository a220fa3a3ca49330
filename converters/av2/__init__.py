"""Argoverse 2 sensor logs -> ``SceneLog``: one module per part of a log (poses, lidar, cameras,
annotations, calibration, map files, vector map), assembled by :mod:`converters.av2.reader`."""

from converters.av2.errors import AV2LogError
from converters.av2.logs import find_logs
from converters.av2.reader import read_log
from converters.av2.sync import SyncedSweep, synced_sweeps

__all__ = ["AV2LogError", "SyncedSweep", "find_logs", "read_log", "synced_sweeps"]
