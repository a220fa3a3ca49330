"""The driver's one progress display for a batch of logs (or scenes), built on
:func:`nuav2.progress.progress_bar`: a tqdm bar on a terminal, otherwise a log line every few seconds."""

from __future__ import annotations

import time

from nuav2.progress import LINE_INTERVAL_S, progress_bar, stderr_is_tty


class BatchProgress:
    """Done / failed / running and the time left, for the local and the Ray executor alike.

    ``running`` is the number of items occupying a worker slot (in flight, capped by the slots). The
    time left is elapsed / done x remaining (tqdm computes its own on a terminal).
    """

    def __init__(self, total: int, *, enabled: bool = True, desc: str = "convert", unit: str = "log",
                 line_every_s: float = LINE_INTERVAL_S) -> None:
        self.total = total
        self.done = self.failed = self.running = 0
        self.enabled = enabled and total > 0
        self.tty = self.enabled and stderr_is_tty()
        self.line_every_s = line_every_s
        self.t0 = time.perf_counter()
        extra = {} if self.tty else {"interval_s": line_every_s}
        self.bar = progress_bar(total=total, desc=desc, unit=unit, disable=not self.enabled, **extra)

    def update(self, *, running: int | None = None, finished: int = 0, failed: int = 0) -> None:
        """Record ``finished`` more items (``failed`` of them failed) and the current running count."""
        self.done += finished
        self.failed += failed
        if running is not None:
            self.running = running
        self.running = min(self.running, self.total - self.done)  # the last line said running=1
        postfix = {"failed": self.failed, "running": self.running}
        if not self.tty:
            eta = self.eta_s()
            postfix["left"] = "?" if eta is None else f"{eta:.0f} s"
        self.bar.set_postfix(postfix, refresh=False)
        self.bar.update(finished)

    def eta_s(self) -> float | None:
        if not self.done:
            return None
        return (time.perf_counter() - self.t0) / self.done * (self.total - self.done)

    def close(self) -> None:
        self.bar.close()
