"""The driver's one progress display for a batch of logs: a bar on a terminal, a line every few seconds
elsewhere (a log file fills with nothing but carriage-return updates otherwise)."""

from __future__ import annotations

import sys
import time

from tqdm import tqdm

LINE_EVERY_S = 10.0


class BatchProgress:
    """Logs done / failed / running and the time left, for the local and the Ray executor alike.

    ``running`` is the number of logs occupying a worker slot (in flight, capped by the slots), so
    the time left is (remaining logs / slots) x the mean seconds per finished log and slot.
    """

    def __init__(self, total: int, *, enabled: bool = True, desc: str = "convert", unit: str = "log",
                 line_every_s: float = LINE_EVERY_S, stream=None) -> None:
        self.total, self.desc, self.unit = total, desc, unit
        self.done = self.failed = self.running = 0
        self.stream = stream or sys.stderr
        self.enabled = enabled and total > 0
        self.tty = self.enabled and bool(getattr(self.stream, "isatty", lambda: False)())
        self.line_every_s = line_every_s
        self.t0 = time.perf_counter()
        self._last_line = self.t0
        self.bar = tqdm(total=total, desc=desc, unit=unit, file=self.stream, disable=not self.tty,
                        dynamic_ncols=True)

    def update(self, *, running: int | None = None, finished: int = 0, failed: int = 0) -> None:
        """Record ``finished`` more logs (``failed`` of them failed) and the current running count."""
        self.done += finished
        self.failed += failed
        if running is not None:
            self.running = running
        if self.tty:
            self.bar.set_postfix(failed=self.failed, running=self.running, refresh=False)
            self.bar.update(finished)
        elif self.enabled and time.perf_counter() - self._last_line >= self.line_every_s:
            self._print_line()

    def eta_s(self) -> float | None:
        if not self.done:
            return None
        elapsed = time.perf_counter() - self.t0
        return elapsed / self.done * (self.total - self.done)

    def _print_line(self) -> None:
        self._last_line = time.perf_counter()
        eta = self.eta_s()
        eta_txt = "?" if eta is None else tqdm.format_interval(eta)
        print(f"{self.desc}: {self.done}/{self.total} {self.unit}s done, {self.failed} failed, "
              f"{self.running} running, {tqdm.format_interval(self._last_line - self.t0)} elapsed, "
              f"ETA {eta_txt}", file=self.stream, flush=True)

    def close(self) -> None:
        if self.enabled and not self.tty:
            self.running = 0
            self._print_line()
        self.bar.close()
