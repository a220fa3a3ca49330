"""Progress display: a bar only on a terminal; elsewhere at most a log line every few seconds (finding 14)."""

from __future__ import annotations

import io
import logging

from tqdm import tqdm

from nuav2 import progress
from nuav2.progress import LineProgress, progress_bar


class _Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_a_terminal_gets_a_tqdm_bar(monkeypatch):
    monkeypatch.setattr("sys.stderr", _Tty())
    bar = progress_bar(range(3), desc="x")
    assert isinstance(bar, tqdm)
    assert list(bar) == [0, 1, 2]


def test_a_log_file_gets_no_carriage_returns_and_few_lines(monkeypatch, capsys, caplog):
    caplog.set_level(logging.INFO, logger="nuav2.progress")
    clock = iter(range(0, 100_000, 1))  # one "second" per call
    monkeypatch.setattr(progress.time, "monotonic", lambda: float(next(clock)))
    bar = progress_bar(range(1000), desc="map GT", unit="sample")
    assert isinstance(bar, LineProgress)
    assert list(bar) == list(range(1000))
    err = capsys.readouterr().err
    assert "\r" not in err and err == ""
    lines = [r.getMessage() for r in caplog.records]
    elapsed = [int(line.rsplit("(", 1)[1].split()[0]) for line in lines]
    assert len(lines) >= 2 and all(b - a >= progress.LINE_INTERVAL_S for a, b in zip(elapsed, elapsed[1:-1]))
    assert lines[-1].startswith("map GT: 1000/1000 sample")


def test_short_work_and_disabled_bars_print_nothing(caplog):
    caplog.set_level(logging.INFO, logger="nuav2.progress")
    assert list(progress_bar(range(5), desc="quick")) == list(range(5))
    bar = progress_bar(total=10, desc="off", disable=True, initial=2)
    bar.update(3)
    bar.set_postfix(loss="0.1")
    bar.close()
    assert bar.n == 5 and caplog.records == []
