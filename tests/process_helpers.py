"""Helpers of the tests that run nuav2 as a child process and stop it (Ctrl-C, SIGTERM)."""

from __future__ import annotations

import signal
import subprocess
import time
from collections.abc import Callable
from pathlib import Path


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


def signal_state(pid: int) -> str:
    """The process's blocked / ignored / caught signal masks (``/proc/PID/status``), for a failure
    message: a signal that had no effect was blocked, ignored, or lost."""
    try:
        lines = Path(f"/proc/{pid}/status").read_text().splitlines()
    except OSError as e:
        return f"no /proc status: {e}"
    return " ".join(ln.replace("\t", "") for ln in lines if ln.startswith(("SigBlk", "SigIgn", "SigCgt")))


def interrupt(proc: subprocess.Popen, timeout_s: float = 60.0,
              again_after_s: float = 10.0) -> tuple[str, str, int]:
    """Ctrl-C ``proc`` (SIGINT), and again if it is still running ``again_after_s`` later, as a user
    would. Seen once in a full run here: the first SIGINT had no effect (exit 0, nothing on stderr, the
    log complete). Our guess: the KeyboardInterrupt was raised while C code ran Python for it and was
    cleared with that code's error (``PyObject_HasAttr`` and library fallbacks do that). Returns
    (stderr, the signal masks before the first, how many SIGINTs were sent): a second one can reach
    a process that handled the first and is still exiting, whose interpreter has by then given
    SIGINT back its default action, so it ends by the signal (-2) instead of its exit code."""
    state = signal_state(proc.pid)
    end = time.monotonic() + timeout_s
    sent = 0
    while True:
        proc.send_signal(signal.SIGINT)
        sent += 1
        try:
            _, err = proc.communicate(timeout=min(again_after_s, max(0.1, end - time.monotonic())))
            return err, state, sent
        except subprocess.TimeoutExpired:
            assert time.monotonic() < end, f"still running {timeout_s:.0f} s after SIGINT; before it: {state}"
