"""The ``nuav2`` entry point: a Ctrl-C while the CLI is still importing its libraries."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from process_helpers import default_sigint

ROOT = Path(__file__).resolve().parent.parent


def _importing_libraries(pid: int) -> bool:
    """The process has mapped numpy's extension: past Python's own start-up (where a Ctrl-C is
    Python's fatal error, not ours) and into the CLI's imports, which take about a second."""
    try:
        return "numpy" in Path(f"/proc/{pid}/maps").read_text()
    except OSError:
        return False


def test_ctrl_c_during_start_up_says_interrupted_without_a_traceback(tmp_path: Path):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    # synth runs for seconds, so the signal cannot arrive after the work, whatever the machine's load
    argv = [sys.executable, "-m", "nuav2", "synth", str(tmp_path / "logs"), "--seconds", "3"]
    proc = subprocess.Popen(argv, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            preexec_fn=default_sigint)
    try:
        end = time.monotonic() + 30
        while not _importing_libraries(proc.pid) and proc.poll() is None and time.monotonic() < end:
            time.sleep(0.001)
        assert proc.poll() is None, "nuav2 finished before the interrupt could be sent"
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 130 and err.strip().splitlines() == ["interrupted"], (proc.returncode, err)
    assert not (tmp_path / "logs").exists()


def test_the_entry_point_runs_outside_the_main_thread(monkeypatch, capsys):
    """Only the main thread may set signal handlers: elsewhere the hold is skipped, not a crash."""
    import threading

    from nuav2 import entry

    monkeypatch.setattr(sys, "argv", ["nuav2", "validate", "/nonexistent/db"])
    codes: list = []

    def target() -> None:
        try:
            entry.run()
        except SystemExit as e:
            codes.append(e.code)
        except BaseException as e:  # noqa: BLE001 - the failure the test reports
            codes.append(repr(e))

    worker = threading.Thread(target=target)
    worker.start()
    worker.join(60)
    assert codes == [2] and "dataroot not found" in capsys.readouterr().err


def test_an_error_raised_while_a_ctrl_c_unwinds_reads_as_interrupted(monkeypatch, capsys, tmp_path: Path):
    """numba's dispatcher turns a KeyboardInterrupt inside compiled code into a SystemError ("returned
    a result with an exception set"), seen once at a Ctrl-C of ``bench raster``: it printed
    "internal error" and exit 2."""
    import nuav2.commands.validate as validate_cmd
    from nuav2.cli import main

    def interrupted_in_compiled_code(args):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt:
            raise SystemError("CPUDispatcher(bin_rows) returned a result with an exception set") from None

    monkeypatch.setattr(validate_cmd, "run", interrupted_in_compiled_code)
    assert main(["validate", str(tmp_path)]) == 130
    assert capsys.readouterr().err.strip().splitlines() == ["interrupted"]

    def unrelated(args):
        try:
            raise ValueError("first")
        except ValueError:
            raise SystemError("second") from None

    monkeypatch.setattr(validate_cmd, "run", unrelated)
    assert main(["validate", str(tmp_path)]) == 2
    assert "internal error: SystemError: second" in capsys.readouterr().err
