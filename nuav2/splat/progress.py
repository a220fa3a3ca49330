"""Progress of long reconstruction steps: a tqdm bar on a terminal, one log line every few seconds otherwise.

A render-mode conversion spends minutes in seeding and training; a user watching a terminal
sees a bar with the current status (step, PSNR, Gaussians), and a log file or CI console gets
a plain ``INFO`` line every ``every_s`` seconds (and one at the end) instead of carriage-return
bar updates.
"""

from __future__ import annotations

import logging
import sys
import time
from typing import TextIO

from tqdm import tqdm

log = logging.getLogger("nuav2.recon")


def is_terminal(stream: TextIO | None) -> bool:
    try:
        return bool(stream is not None and stream.isatty())
    except (AttributeError, ValueError):  # closed or exotic streams
        return False


class Progress:
    """``update(n, **status)`` per step; ``close()`` at the end (also a context manager).

    ``enabled=False`` shows nothing. On a terminal (``stream``, default stderr) a bar whose
    postfix is the status; otherwise a log line at most every ``every_s`` seconds and a last
    one at ``close``.
    """

    def __init__(self, total: int | None, desc: str, *, enabled: bool = True, initial: int = 0,
                 unit: str = "it", every_s: float = 10.0, stream: TextIO | None = None,
                 logger: logging.Logger | None = None) -> None:
        self.total, self.desc, self.unit, self.every_s = total, desc, unit, float(every_s)
        self.n = int(initial)
        self.status: dict[str, object] = {}
        self.log = logger or log
        stream = sys.stderr if stream is None else stream
        self.bar = None
        self.lines = enabled and not is_terminal(stream)
        if enabled and not self.lines:
            self.bar = tqdm(total=total, initial=initial, desc=desc, unit=unit, file=stream, leave=False,
                            mininterval=min(self.every_s, 0.1))
        self.t0 = self.t_last = time.perf_counter()
        self.n0 = self.n

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def set_total(self, total: int) -> None:
        self.total = total
        if self.bar is not None:
            self.bar.total = total
            self.bar.refresh()

    def update(self, n: int = 1, **status) -> None:
        self.n += n
        self.status.update(status)
        if self.bar is not None:
            self.bar.update(n)
            if status:
                self.bar.set_postfix({k: format_value(v) for k, v in self.status.items()}, refresh=False)
        elif self.lines and time.perf_counter() - self.t_last >= self.every_s:
            self._line()

    def _line(self, done: bool = False) -> None:
        now = time.perf_counter()
        self.t_last = now
        dt = now - self.t0
        rate = (self.n - self.n0) / dt if dt > 0 else 0.0
        of = f"/{self.total}" if self.total is not None else ""
        parts = [f"{self.n}{of} {self.unit}", f"{rate:.1f} {self.unit}/s", f"{dt:.0f} s"]
        parts += [f"{k} {format_value(v)}" for k, v in self.status.items()]
        self.log.info("%s%s: %s", self.desc, " done" if done else "", ", ".join(parts))

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None
        elif self.lines:
            self._line(done=True)
            self.lines = False


def format_value(v: object) -> str:
    if isinstance(v, float):
        return f"{v:.2f}"
    if isinstance(v, int) and not isinstance(v, bool) and abs(v) >= 10_000:
        return f"{v:,}"
    return str(v)
