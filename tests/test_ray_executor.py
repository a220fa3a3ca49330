"""``convert --executor ray`` on a local Ray cluster (loopback, 2 CPUs, no dashboard): byte-identical
tables, a killed worker retried, a bad log reported once, resume, the shared-storage check."""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

import pytest
from test_executor_support import VERSION, convert, corrupt_copy, descendants_named, infos_files, tables

from nuav2.convert import ConvertError, ConvertOptions
from nuav2.executors.task import FAULT_ENV
from nuav2.nuscenes_db.shards import SHARDS_DIRNAME

ray = pytest.importorskip("ray", reason="the ray package is not installed (pip install 'nuav2[ray]')")

pytest_plugins = ["test_executor_support"]  # the synth_split, reference_out and reference_tables fixtures


@pytest.fixture(scope="module")
def local_ray():
    """One local Ray instance for the module; the executor uses it and leaves it running."""
    if not sys.platform.startswith("linux"):
        pytest.skip("the process checks read /proc")
    ray.init(num_cpus=2, include_dashboard=False, object_store_memory=128 * 2**20, log_to_driver=False)
    yield ray
    ray.shutdown()
    assert not descendants_named({"raylet", "gcs_server"}), "Ray processes left behind after shutdown"


def test_ray_tables_are_identical_to_one_local_worker_and_a_rerun_resumes(
        local_ray, synth_split: Path, reference_tables: dict, tmp_path: Path):
    out = tmp_path / "out"
    assert convert(synth_split, out, "--executor", "ray") == 0
    assert tables(out) == reference_tables
    report = json.loads((out / "convert_report.json").read_text())
    assert sorted(report["logs"]) == sorted(report["converted"]) and len(report["converted"]) == 3
    for summary in report["logs"].values():
        assert summary["mode"] == "native" and summary["images"] > 0 and summary["seconds"] > 0
        assert summary["node"] and summary["gpus"] == []
    assert not list((out / SHARDS_DIRNAME).glob(".nuav2-visible-*"))  # the driver's marker is removed

    # A killed driver: one shard and the merged tables gone, a half-written shard and the driver's
    # marker left behind (found by review: the marker stayed in OUT through every later run).
    first, second, third = sorted(report["converted"])
    shutil.rmtree(out / SHARDS_DIRNAME / VERSION / second)
    shutil.rmtree(out / VERSION)
    (out / SHARDS_DIRNAME / VERSION / f".{second}.x.partial").mkdir()
    (out / SHARDS_DIRNAME / ".nuav2-visible-0123abcd").write_text("0123abcd")  # its marker, left for good
    assert convert(synth_split, out, "--executor", "ray") == 0
    assert not list((out / SHARDS_DIRNAME).glob(".nuav2-visible-*"))
    report = json.loads((out / "convert_report.json").read_text())
    assert report["resumed"] == [first, third] and report["converted"] == [second]
    assert tables(out) == reference_tables


def test_ray_warp_mode_writes_the_same_tables_and_images_as_one_local_worker(
        local_ray, synth_split: Path, tmp_path: Path):
    src = tmp_path / "src"
    src.mkdir()
    for log_dir in sorted(synth_split.iterdir())[:2]:
        (src / log_dir.name).symlink_to(log_dir, target_is_directory=True)
    warp = ("--mode", "warp", "--scale", "0.125")
    assert convert(src, tmp_path / "local", *warp) == 0
    assert convert(src, tmp_path / "ray", *warp, "--executor", "ray") == 0
    assert tables(tmp_path / "ray") == tables(tmp_path / "local")
    images = {p.relative_to(tmp_path / "local"): p.read_bytes()
              for p in sorted((tmp_path / "local" / "samples").rglob("*.jpg"))}
    assert len(images) == 2 * 5 * 6  # 2 logs x 5 samples x 6 nuScenes cameras
    assert images == {p.relative_to(tmp_path / "ray"): p.read_bytes()
                      for p in sorted((tmp_path / "ray" / "samples").rglob("*.jpg"))}


def test_a_worker_killed_mid_log_is_retried_and_the_tables_stay_identical(
        local_ray, synth_split: Path, reference_tables: dict, tmp_path: Path, monkeypatch):
    hook = tmp_path / "hook"
    hook.mkdir()
    monkeypatch.setenv(FAULT_ENV, f"kill:{hook}")
    out = tmp_path / "out"
    assert convert(synth_split, out, "--executor", "ray") == 0
    attempts = {p.name.split(".")[0]: p.read_text().split() for p in hook.glob("*.attempts")}
    assert len(attempts) == 3 and all(len(pids) == 2 for pids in attempts.values())  # killed once, redone
    assert tables(out) == reference_tables


def test_a_bad_log_is_reported_once_and_the_others_merge(
        local_ray, synth_split: Path, tmp_path: Path, monkeypatch, capsys):
    logs = sorted(p.name for p in synth_split.iterdir())
    src = tmp_path / "src"
    sweep = corrupt_copy(synth_split, src, logs[1])
    hook = tmp_path / "hook"
    hook.mkdir()
    monkeypatch.setenv(FAULT_ENV, f"record:{hook}")
    out = tmp_path / "out"
    assert convert(src, out, "--executor", "ray") == 1  # 1: some logs failed
    report = json.loads((out / "convert_report.json").read_text())
    assert [f["log_id"] for f in report["failed"]] == [logs[1]] and sweep.name in report["failed"][0]["error"]
    assert report["converted"] == [logs[0], logs[2]]
    assert len((hook / f"{logs[1]}.attempts").read_text().split()) == 1  # not retried
    assert sorted(s["description"] for s in json.loads((out / VERSION / "scene.json").read_text())) == \
        [logs[0], logs[2]]
    assert f"failed: {src / logs[1]}" in capsys.readouterr().err


def test_a_log_that_kills_every_worker_is_retried_a_bounded_number_of_times(
        local_ray, synth_split: Path, tmp_path: Path, monkeypatch):
    logs = sorted(p.name for p in synth_split.iterdir())
    src = tmp_path / "src"
    src.mkdir()
    for name in logs[:2]:
        shutil.copytree(synth_split / name, src / name)
    hook = tmp_path / "hook"
    hook.mkdir()
    monkeypatch.setenv(FAULT_ENV, f"crash:{hook}")
    out = tmp_path / "out"
    assert convert(src, out, "--executor", "ray", "--max-retries", "1") == 2  # every log died
    report = json.loads((out / "convert_report.json").read_text())
    assert sorted(f["log_id"] for f in report["failed"]) == logs[:2]
    assert all("after 1 retries" in f["error"] for f in report["failed"])
    assert all(len(p.read_text().split()) == 2 for p in hook.glob("*.attempts"))  # 1 try + 1 retry each
    assert not (out / "samples").exists() and not (out / "sweeps").exists()  # killed logs' files removed


def test_ray_infos_are_byte_identical_to_one_process(local_ray, reference_out: Path, tmp_path: Path):
    one = infos_files(reference_out, tmp_path / "one")
    assert infos_files(reference_out, tmp_path / "ray", "--executor", "ray", "--workers", "2") == one


def test_out_invisible_on_a_node_stops_with_an_error_naming_it(local_ray, tmp_path: Path):
    from nuav2.executors.ray_tasks import check_shared_storage

    with pytest.raises(ConvertError, match=r"not visible on every Ray node.*cannot read .*nuav2-visible"):
        check_shared_storage(local_ray, tmp_path, "a-marker-the-driver-never-wrote")


def test_render_tasks_ask_for_a_gpu_only_where_the_cluster_has_gpus():
    from nuav2.executors.ray_tasks import slots, task_resources

    render = ConvertOptions(mode="render", executor="ray")
    gpu_cluster = {"CPU": 64.0, "GPU": 8.0, "memory": 512 * 2**30}
    assert task_resources(gpu_cluster, render)["num_gpus"] == 1.0
    assert slots(gpu_cluster, task_resources(gpu_cluster, render)) == 8
    cpu_cluster = {"CPU": 16.0, "memory": 64 * 2**30}
    assert task_resources(cpu_cluster, render)["num_gpus"] == 0.0
    assert slots(cpu_cluster, task_resources(cpu_cluster, render)) == 8  # 2 CPUs per render task
    assert task_resources(gpu_cluster, ConvertOptions(mode="warp", executor="ray"))["num_gpus"] == 0.0
    forced_cpu = ConvertOptions(mode="render", executor="ray", gpus_per_task=0, cpus_per_task=4,
                                memory_per_task_gb=0)
    assert task_resources(gpu_cluster, forced_cpu) == {"num_cpus": 4.0, "num_gpus": 0.0}


def test_without_ray_installed_the_executor_is_a_one_line_error(synth_split: Path, tmp_path: Path,
                                                                monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "ray", None)  # what `import ray` sees where ray is not installed
    assert convert(synth_split, tmp_path / "out", "--executor", "ray") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["nuav2 convert: --executor ray needs the ray package (pip install 'nuav2[ray]')"]
    assert not (tmp_path / "out").exists()
