"""What a conversion reports: the logs converted, resumed, merged from earlier runs and failed, and the
tables written, as ``OUT/convert_report.json`` (the CLI prints it; a batch's failures are listed there)."""

from __future__ import annotations

import logging
from dataclasses import asdict, dataclass, field
from pathlib import Path

from nuav2.atomic import atomic_write_json

log = logging.getLogger(__name__)

REPORT_FILE = "convert_report.json"


@dataclass
class ConvertReport:
    dataroot: str
    version: str
    converted: list[str] = field(default_factory=list)
    resumed: list[str] = field(default_factory=list)
    merged_earlier: list[str] = field(default_factory=list)  # shards in OUT from earlier runs (other SRC)
    failed: list[dict] = field(default_factory=list)  # {"log_id", "log_dir", "error"}
    scene_names: dict[str, str] = field(default_factory=dict)
    table_counts: dict[str, int] = field(default_factory=dict)
    logs: dict[str, dict] = field(default_factory=dict)  # per log run now: seconds, images, mode, worker

    @property
    def ok(self) -> bool:
        return not self.failed and bool(self.table_counts)

    def to_dict(self) -> dict:
        return asdict(self)


def write_report(out: Path, report: ConvertReport) -> bool:
    """Write ``convert_report.json``; False (logged) when it cannot be written."""
    try:
        atomic_write_json(out / REPORT_FILE, report.to_dict(), indent=1)
        return True
    except OSError as e:
        log.error("%s: cannot write the conversion report (%s)", out / REPORT_FILE, e.strerror or e)
        return False
