"""The cluster recipe of docs/cluster.md on this machine: a head started with ``ray start --head``,
then ``convert`` and ``infos`` with ``--ray-address HOST:PORT``; and a dead address is one line."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest
from process_helpers import default_sigint, wait_while_running
from test_executor_support import VERSION, convert, descendants_named, infos_files, tables

from nuav2.cli import main

ray = pytest.importorskip("ray", reason="the ray package is not installed (pip install 'nuav2[ray]')")

pytest_plugins = ["test_executor_support"]  # the synth_split, reference_out and reference_tables fixtures

REPO = Path(__file__).resolve().parent.parent
RAY_CLI = Path(sys.executable).parent / "ray"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _head_is_up(address: str, env: dict) -> bool:
    """`ray status` answers, with or without the token that `ray start --head` may have enabled."""
    return any(subprocess.run([str(RAY_CLI), "status", "--address", address], env={**env, **auth},
                              capture_output=True, timeout=60).returncode == 0
               for auth in ({}, {"RAY_AUTH_MODE": "token"}))


@pytest.fixture
def ray_head():
    """``ray start --head --block`` on a free port (2 CPUs, no dashboard); SIGTERM stops all it started."""
    if not RAY_CLI.is_file():
        pytest.skip(f"{RAY_CLI}: Ray's command line is not beside this Python")
    if not sys.platform.startswith("linux"):
        pytest.skip("the process checks read /proc")
    port = _free_port()
    address = f"127.0.0.1:{port}"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    head = subprocess.Popen([str(RAY_CLI), "start", "--head", f"--port={port}", "--num-cpus=2",
                             "--include-dashboard=false", "--disable-usage-stats", "--block"],
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        end = time.monotonic() + 120
        while not _head_is_up(address, env):
            assert head.poll() is None and time.monotonic() < end, "ray start --head did not come up"
            time.sleep(1.0)
        yield address
    finally:
        head.send_signal(signal.SIGTERM)
        head.wait(60)
        current = Path(tempfile.gettempdir()) / "ray" / "ray_current_cluster"  # Ray's pointer to this head
        if current.is_file() and current.read_text().strip().endswith(f":{port}"):
            current.unlink()
    assert not descendants_named({"raylet", "gcs_server"}), "the head left Ray processes behind"


def test_convert_and_infos_on_a_cluster_started_with_ray_start(
        ray_head: str, synth_split: Path, reference_out: Path, reference_tables: dict, tmp_path: Path):
    assert not ray.is_initialized()
    out = tmp_path / "out"
    assert convert(synth_split, out, "--executor", "ray", "--ray-address", ray_head) == 0
    assert tables(out) == reference_tables
    report = json.loads((out / "convert_report.json").read_text())
    assert len(report["converted"]) == 3 and all(s["node"] for s in report["logs"].values())
    one = infos_files(out, tmp_path / "one")
    assert infos_files(out, tmp_path / "ray", "--executor", "ray", "--ray-address", ray_head) == one


def test_an_address_with_no_cluster_is_a_one_line_error(synth_split: Path, tmp_path: Path, capsys):
    address = f"127.0.0.1:{_free_port()}"  # nothing listens there
    assert convert(synth_split, tmp_path / "out", "--executor", "ray", "--ray-address", address) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert err[0].startswith(f"nuav2 convert: --ray-address: Ray cluster '{address}' does not answer")
    assert not (tmp_path / "out").exists()


def test_a_local_ray_that_cannot_start_is_a_one_line_error(synth_split: Path, reference_out: Path,
                                                           tmp_path: Path, monkeypatch, capsys):
    assert not ray.is_initialized()
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    monkeypatch.setenv("RAY_TMPDIR", str(blocker / "tmp"))  # Ray cannot make its session folder under a file
    assert convert(synth_split, tmp_path / "out", "--executor", "ray") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert err[0].startswith("nuav2 convert: --executor ray: a local Ray instance did not start (")
    assert "Not a directory" in err[0] and f"Ray's logs: {blocker / 'tmp'}" in err[0]
    assert not ray.is_initialized() and not (tmp_path / "out").exists()  # no empty OUT left behind
    argv = ["infos", str(reference_out), "--version", VERSION, "--out", str(tmp_path / "infos")]
    assert main([*argv, "--executor", "ray"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert err[0].startswith("nuav2 infos: --executor ray: a local Ray instance did not start (")


def test_a_local_ray_gets_a_whole_number_of_cpus():
    """Ray 2.60 hands its raylet ``min(cores, num_cpus)`` as an integer flag: ``--workers 2
    --cpus-per-task 4`` (8.0) stopped the raylet on a 16-core machine, and 1.5 is refused outright."""
    from nuav2.executors.ray_tasks import connected, whole_cpus

    assert [whole_cpus(n) for n in (None, 8.0, 1.5, 0.25)] == [None, 8, 2, 1]
    assert all(type(whole_cpus(n)) is int for n in (8.0, 1.5, 0.25))
    assert not ray.is_initialized()
    with connected(None, num_cpus=1.5) as r:  # before: "Resource quantities must all be whole numbers"
        assert r.cluster_resources()["CPU"] == 2
    assert not ray.is_initialized()


def test_a_local_ray_runs_no_more_logs_at_once_than_workers():
    """``--workers 3 --cpus-per-task 0.5`` rounds up to 2 CPUs, room for 4 half-CPU tasks; the
    local instance's log slots keep it at 3."""
    from nuav2.convert import ConvertOptions
    from nuav2.executors.ray_tasks import LOG_SLOT, connected, slots, task_resources

    options = ConvertOptions(mode="native", executor="ray", workers=3, cpus_per_task=0.5,
                             memory_per_task_gb=0)
    assert not ray.is_initialized()
    with connected(None, num_cpus=1.5, log_slots=3) as r:
        cluster = r.cluster_resources()
        res = task_resources(cluster, options)
        assert cluster["CPU"] == 2 and res["resources"] == {LOG_SLOT: 1.0}
        assert slots(cluster, res) == 3
        assert slots(cluster, {k: v for k, v in res.items() if k != "resources"}) == 4  # without them

        @r.remote
        def span(_):
            import time
            start = time.monotonic()
            time.sleep(0.5)
            return start, time.monotonic()

        spans = r.get([span.options(**res).remote(i) for i in range(8)])
        at_once = max(sum(s <= t < e for s, e in spans) for t, _ in spans)
        assert 1 <= at_once <= 3
    assert not ray.is_initialized()
    assert "resources" not in task_resources({"CPU": 8.0}, options)  # clusters without slots


def test_an_interrupted_ray_driver_cancels_its_running_logs_so_they_clean_up(
        synth_split: Path, tmp_path: Path):
    """SIGTERM / Ctrl-C on the driver: running tasks get Ray's cancel (a KeyboardInterrupt, which
    unwinds a log's cleanup) before the local Ray instance stops, instead of being killed mid-write."""
    from nuav2.executors.task import FAULT_ENV

    hook = tmp_path / "hook"
    hook.mkdir()
    env = {**os.environ, FAULT_ENV: f"hang:{hook}", "PYTHONPATH": str(REPO)}
    driver = subprocess.Popen([sys.executable, "-m", "nuav2", "convert", "av2", str(synth_split),
                               str(tmp_path / "out"), "--executor", "ray", "--workers", "2", "--no-progress"],
                              env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                              preexec_fn=default_sigint)  # Ray's cancel raises through SIGINT
    try:
        wait_while_running(driver, lambda: len(list(hook.glob("*.attempts"))) == 2, 180,
                           "the Ray tasks never started", poll_s=0.5)
        driver.send_signal(signal.SIGTERM)
        _, err = driver.communicate(timeout=120)
    finally:
        driver.kill()
    assert driver.returncode == 143 and err.strip().splitlines()[-1] == "terminated", err
    assert sorted(f.read_text() for f in hook.glob("*.stopped")) == ["KeyboardInterrupt"] * 2
    assert not (tmp_path / "out" / VERSION).exists()
