"""Progress display that suits where the output goes: a tqdm bar on a terminal, log lines elsewhere.

A tqdm bar redraws itself with carriage returns several times a second; written to a log file
that is hundreds of kilobytes of noise. So :func:`progress_bar` returns a real bar only when stderr
is a terminal; otherwise it returns a :class:`LineProgress` that logs one line (``desc: n/total
unit``, plus the postfix) at most every ``LINE_INTERVAL_S`` seconds and once at the end.
Both take tqdm's arguments (``desc``, ``total``, ``unit``, ``disable``, ``leave``, ``initial``),
iterate, and have ``update``, ``set_postfix``, ``set_description`` and ``close``.
"""

from __future__ import annotations

import logging
import sys
import time
from collections.abc import Iterable, Iterator
from typing import Any

log = logging.getLogger(__name__)

LINE_INTERVAL_S = 10.0


def stderr_is_tty() -> bool:
    isatty = getattr(sys.stderr, "isatty", None)
    try:
        return bool(isatty and isatty())
    except ValueError:  # closed stream
        return False


class LineProgress:
    """tqdm's interface without the bar: one log line per ``interval_s`` (none when disabled)."""

    def __init__(self, iterable: Iterable | None = None, desc: str = "", total: float | None = None,
                 unit: str = "it", disable: bool = False, initial: float = 0,
                 interval_s: float = LINE_INTERVAL_S, **_ignored: Any) -> None:
        self.iterable = iterable
        self.desc = desc
        if total is None and iterable is not None and hasattr(iterable, "__len__"):
            total = len(iterable)  # type: ignore[arg-type]
        self.total = total
        self.unit = unit
        self.disable = disable
        self.n = initial
        self.postfix = ""
        self.interval_s = interval_s
        self._start = time.monotonic()
        self._last = self._start
        self._closed = False
        self._logged_n: float | None = None

    def __iter__(self) -> Iterator:
        if self.iterable is None:
            raise TypeError("LineProgress was created without an iterable")
        try:
            for item in self.iterable:
                yield item
                self.update()
        finally:
            self.close()

    def __len__(self) -> int:
        return int(self.total or 0)

    def __enter__(self) -> LineProgress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def update(self, n: float = 1) -> None:
        self.n += n
        now = time.monotonic()
        if not self.disable and now - self._last >= self.interval_s:
            self._last = now
            self._emit()

    def set_postfix(self, ordered_dict: dict | None = None, refresh: bool = True, **kwargs: Any) -> None:
        items = {**(ordered_dict or {}), **kwargs}
        self.postfix = ", ".join(f"{k}={v}" for k, v in items.items())

    def set_postfix_str(self, s: str = "", refresh: bool = True) -> None:
        self.postfix = s

    def set_description(self, desc: str | None = None, refresh: bool = True) -> None:
        self.desc = desc or ""

    def refresh(self) -> None:
        pass

    def line(self) -> str:
        """``desc: n/total unit [postfix] (elapsed)``: what one log line says."""
        count = f"{self.n:g}/{self.total:g}" if self.total else f"{self.n:g}"
        extra = f" [{self.postfix}]" if self.postfix else ""
        return f"{self.desc}: {count} {self.unit}{extra} ({time.monotonic() - self._start:.0f} s)"

    def _emit(self) -> None:
        self._logged_n = self.n
        log.info("%s", self.line())

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        # A final line only for work that took long enough to have been reported along the way.
        if not self.disable and self._logged_n is not None and self._logged_n != self.n:
            self._emit()


def progress_bar(iterable: Iterable | None = None, **kwargs: Any):
    """A tqdm bar when stderr is a terminal, else a :class:`LineProgress` (same arguments as tqdm)."""
    if stderr_is_tty() and not kwargs.get("disable", False):
        from tqdm import tqdm

        return tqdm(iterable, **kwargs)
    return LineProgress(iterable, **kwargs)
