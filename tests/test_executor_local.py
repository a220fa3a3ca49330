"""The local executor: workers exit when the main process dies; a dead worker's log is retried (bounded)."""

from __future__ import annotations

import contextlib
import json
import logging
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

from process_helpers import default_sigint
from test_executor_support import VERSION, convert, tables

from nuav2.executors.progress import BatchProgress
from nuav2.executors.task import FAULT_ENV

pytest_plugins = ["test_executor_support"]  # the synth_split and reference_tables fixtures

REPO = Path(__file__).resolve().parent.parent


def _alive(pid: int) -> bool:
    """True while ``pid`` runs (a zombie waiting for its reaper counts as gone)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, IndexError):
        return False
    return state != "Z"


def _wait_for(predicate, timeout_s: float) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(0.2)
    return predicate()


def test_workers_exit_when_the_main_process_is_killed(synth_split: Path, tmp_path: Path):
    hook = tmp_path / "hook"
    hook.mkdir()
    env = {**os.environ, FAULT_ENV: f"hang:{hook}", "PYTHONPATH": str(REPO)}
    main = subprocess.Popen([sys.executable, "-m", "nuav2", "convert", "av2", str(synth_split),
                             str(tmp_path / "out"), "--workers", "2", "--no-progress"],
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        assert _wait_for(lambda: len(list(hook.glob("*.attempts"))) == 2, 120), "workers never started"
        attempts_before = list(hook.glob("*.attempts"))
        workers = [int(p.read_text().split()[0]) for p in attempts_before]
        assert all(_alive(pid) for pid in workers)
        main.send_signal(signal.SIGKILL)
        main.wait(10)
        assert _wait_for(lambda: not any(_alive(pid) for pid in workers), 15), \
            f"workers {[p for p in workers if _alive(p)]} outlived the killed main process"
        # the third log, queued for the pool: no worker may start it once told to stop (concurrent.futures
        # caught the SystemExit as the task's error and handed the worker the next task)
        assert sorted(p.stem for p in hook.glob("*.attempts")) == sorted(p.stem for p in attempts_before)
        assert len(list(hook.glob("*.stopped"))) == 2  # both parked logs unwound (their cleanup ran)
    finally:
        main.kill()
        for p in hook.glob("*.attempts"):
            for pid in map(int, p.read_text().split()):
                if _alive(pid):
                    os.kill(pid, signal.SIGKILL)
    assert not (tmp_path / "out" / VERSION).exists()


def _start_hanging_conversion(synth_split: Path, tmp_path: Path) -> tuple[subprocess.Popen, list[int]]:
    """``convert --workers 2`` in its own process group, both workers parked at the start of a log."""
    hook = tmp_path / "hook"
    hook.mkdir()
    env = {**os.environ, FAULT_ENV: f"hang:{hook}", "PYTHONPATH": str(REPO)}
    main = subprocess.Popen([sys.executable, "-m", "nuav2", "convert", "av2", str(synth_split),
                             str(tmp_path / "out"), "--workers", "2", "--no-progress"],
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, preexec_fn=default_sigint)
    assert _wait_for(lambda: len(list(hook.glob("*.attempts"))) == 2, 120), "workers never started"
    return main, [int(p.read_text().split()[0]) for p in hook.glob("*.attempts")]


def test_ctrl_c_and_sigterm_stop_a_pool_conversion_and_its_workers(synth_split: Path, tmp_path: Path):
    """Ctrl-C reaches the whole process group: a worker interrupted while idle or holding the pool's
    queue lock hung the pool's shutdown for good (and the third log started after the interrupt).
    ``kill`` (SIGTERM) reaches the main process only; it stops the same way, cleanup included."""
    for name, send, code, said in (("int", lambda m: os.killpg(m.pid, signal.SIGINT), 130, "interrupted"),
                                   ("term", lambda m: m.send_signal(signal.SIGTERM), 143, "terminated")):
        (tmp_path / name).mkdir()
        main, workers = _start_hanging_conversion(synth_split, tmp_path / name)
        try:
            send(main)
            _, err = main.communicate(timeout=60)
            assert main.returncode == code and err.strip().splitlines()[-1] == said, (name, err)
            assert _wait_for(lambda w=workers: not any(_alive(pid) for pid in w), 15), name
            stopped = sorted(f.read_text() for f in (tmp_path / name / "hook").glob("*.stopped"))
            assert stopped == ["SystemExit", "SystemExit"], (name, stopped)  # unwound: cleanup ran
        finally:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(main.pid, signal.SIGKILL)
        assert not (tmp_path / name / "out" / VERSION).exists()


def test_a_killed_worker_is_retried_and_the_tables_stay_identical(
        synth_split: Path, reference_tables: dict, tmp_path: Path, monkeypatch):
    hook = tmp_path / "hook"
    hook.mkdir()
    monkeypatch.setenv(FAULT_ENV, f"kill:{hook}")
    out = tmp_path / "out"
    # A death breaks the whole pool, so logs in flight beside the killed one are redone too, and each
    # log's own kill can cost a round: allow more rounds than logs (the bound is tested below).
    assert convert(synth_split, out, "--workers", "2", "--max-retries", "5") == 0
    attempts = {p.name.split(".")[0]: len(p.read_text().split()) for p in hook.glob("*.attempts")}
    assert len(attempts) == 3 and min(attempts.values()) >= 2  # each log was killed once, then redone
    assert tables(out) == reference_tables


def test_a_log_that_kills_every_worker_is_given_up_after_the_retries(
        synth_split: Path, tmp_path: Path, monkeypatch, capsys):
    hook = tmp_path / "hook"
    hook.mkdir()
    monkeypatch.setenv(FAULT_ENV, f"crash:{hook}")
    out = tmp_path / "out"
    assert convert(synth_split, out, "--workers", "2", "--max-retries", "1") == 2  # nothing converted
    report = json.loads((out / "convert_report.json").read_text())
    assert len(report["failed"]) == 3 and all("worker process died 2 times" in f["error"]
                                              for f in report["failed"])
    assert all(len(p.read_text().split()) <= 2 for p in hook.glob("*.attempts"))
    assert not (out / "samples").exists() and not (out / "sweeps").exists()  # killed logs' files removed
    err = capsys.readouterr().err
    assert "nuav2 convert: no log converted (3 failed; the first: " in err and "::" not in err, err


def test_progress_is_log_lines_when_stderr_is_not_a_terminal_and_the_report_summarises_each_log(
        synth_split: Path, reference_tables: dict, tmp_path: Path):
    out = tmp_path / "out"
    proc = subprocess.run([sys.executable, "-m", "nuav2", "convert", "av2", str(synth_split), str(out),
                           "--workers", "2"], env={**os.environ, "PYTHONPATH": str(REPO)},
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "\r" not in proc.stderr  # no bar redraws in a log file
    report = json.loads((out / "convert_report.json").read_text())
    assert sorted(report["logs"]) == sorted(report["converted"])
    for summary in report["logs"].values():
        assert summary["mode"] == "native" and summary["images"] > 0 and summary["seconds"] > 0
        assert summary["cpu_seconds"] > 0 and summary["peak_rss_mb"] > 0
    assert tables(out) == reference_tables


def test_batch_progress_lines_say_done_failed_running_and_time_left(caplog):
    progress = BatchProgress(3, line_every_s=0.0)
    assert not progress.tty  # pytest captures stderr
    with caplog.at_level(logging.INFO, logger="nuav2.progress"):
        progress.update(running=2)
        progress.update(finished=1, failed=1, running=2)
        progress.update(finished=2)  # as both executors end: the running count set before the last result
        progress.close()
    lines = [r.getMessage() for r in caplog.records]
    assert lines[0].startswith("convert: 0/3 log [failed=0, running=2, left=?]")
    assert re.match(r"convert: 1/3 log \[failed=1, running=2, left=\d+ s\]", lines[1])
    assert lines[-1].startswith("convert: 3/3 log [failed=1, running=0, left=0 s]")


def test_ray_only_flags_are_refused_with_the_local_executor(synth_split: Path, tmp_path: Path, capsys):
    for flag, value in (("--ray-address", "auto"), ("--cpus-per-task", "2"), ("--memory-per-task", "4"),
                        ("--gpus-per-task", "1")):
        assert convert(synth_split, tmp_path / "out", flag, value) == 2
        assert capsys.readouterr().err.strip() == f"nuav2 convert: {flag} applies to --executor ray only"
    assert not (tmp_path / "out").exists()
