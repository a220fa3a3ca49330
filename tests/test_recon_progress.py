"""Progress of long reconstruction steps: a bar on a terminal, plain log lines every few seconds otherwise."""

from __future__ import annotations

import io
import logging

from nuav2.splat.progress import Progress


class FakeTerminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_not_a_terminal_gives_log_lines_with_the_status(caplog):
    stream = io.StringIO()
    with caplog.at_level(logging.INFO, logger="nuav2.recon"):
        with Progress(30, "train abc", stream=stream, every_s=0.0) as bar:
            for i in range(30):
                bar.update(1, psnr=20.0 + i / 10, gaussians=12_345)
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 31  # one per update (every_s=0) and a last one
    assert lines[-1].startswith("train abc done: 30/30 it") and "psnr 22.90" in lines[-1]
    assert "gaussians 12,345" in lines[-1]
    assert stream.getvalue() == ""  # no bar characters in a log file


def test_lines_are_spaced_in_time(caplog):
    with caplog.at_level(logging.INFO, logger="nuav2.recon"):
        with Progress(1000, "seed", stream=io.StringIO(), every_s=3600.0) as bar:
            for _ in range(1000):
                bar.update()
    assert len(caplog.records) == 1  # only the closing line within the hour


def test_a_terminal_gets_a_bar_and_no_log_lines(caplog):
    term = FakeTerminal()
    with caplog.at_level(logging.INFO, logger="nuav2.recon"):
        with Progress(10, "train abc", stream=term, every_s=0.0) as bar:
            for _ in range(10):
                bar.update(1, psnr=21.5)
    assert not caplog.records
    assert "train abc" in term.getvalue() and "psnr=21.50" in term.getvalue()


def test_disabled_shows_nothing(caplog):
    term = FakeTerminal()
    with caplog.at_level(logging.INFO, logger="nuav2.recon"):
        with Progress(5, "x", enabled=False, stream=term, every_s=0.0) as bar:
            bar.update(5, psnr=1.0)
    assert not caplog.records and term.getvalue() == ""
