"""Helpers of the tests that run nuav2 as a child process and stop it (Ctrl-C, SIGTERM)."""

from __future__ import annotations

import signal
import subprocess
import time
from collections.abc import Callable


def default_sigint() -> None:
    """``preexec_fn``: a background job of a non-interactive shell (CI) inherits SIGINT ignored and
    Python keeps it ignored; give the child the default, as a terminal's Ctrl-C finds it."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def wait_while_running(proc: subprocess.Popen, ready: Callable[[], bool], timeout_s: float, what: str,
                       poll_s: float = 0.1) -> None:
    """Poll until ``ready()``; fail naming ``what`` if ``proc`` exits first or time runs out."""
    end = time.monotonic() + timeout_s
    while not ready():
        assert proc.poll() is None and time.monotonic() < end, what
        time.sleep(poll_s)
