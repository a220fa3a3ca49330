"""The reconstruction's device (issue 14): ``ReconConfig.device`` / ``convert --device`` on a CPU machine.

On the CPU, asking for the CPU explicitly changes nothing (bit-equal parameters); asking for CUDA
where there is none is one line naming the knob; checkpoints are device-independent (written on the
CPU, read with ``map_location``, so a GPU-written file resumes here). The CUDA run itself is in
tests/test_recon_cuda.py (skipped without a GPU).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import device_scenes as ds
import pytest
import torch

from nuav2.cli import main
from nuav2.convert import ConvertError, ConvertOptions
from nuav2.recon import ReconConfig, reconstruct
from nuav2.splat.device import DeviceUnavailable, resolve_device
from nuav2.splat.gsplat_backend import gsplat_available
from nuav2.splat.init import initial_scene, source_views
from nuav2.splat.train import CHECKPOINT_FILE, Trainer

pytest_plugins = ["test_writer_support", "e2e_support"]  # render_db: a render-mode conversion by the CLI

CUDA, WHY_NOT = gsplat_available()
no_cuda = pytest.mark.skipif(CUDA, reason="this machine has CUDA and gsplat: auto means CUDA here "
                                          "(the CUDA path is tests/test_recon_cuda.py)")


@pytest.fixture(scope="module")
def tiny_scene(tmp_path_factory):
    return ds.tiny_scene(tmp_path_factory.mktemp("device_log"))


@pytest.fixture(scope="module")
def seeded(tiny_scene):
    """(views, initial scene, sky masks) of the tiny log, seeded once; trainers get copies."""
    views = [v for v in source_views(tiny_scene, 1.0) if v.channel in ds.tiny_recon_config().channels]
    init = initial_scene(tiny_scene, views, ds.TINY_INIT, sh_degree=1, progress=False)
    return views, init.scene, init.sky_masks


@no_cuda
def test_explicit_cpu_is_bit_identical_to_the_default(tiny_scene):
    default = reconstruct(tiny_scene, ds.tiny_recon_config(), progress=False)
    cpu = reconstruct(tiny_scene, ds.tiny_recon_config(device="cpu"), progress=False)
    assert default.info["device"] == cpu.info["device"] == "cpu"
    assert default.info["train"]["densify"], "densification (random split offsets) must have run"
    assert default.objects and default.device == torch.device("cpu")
    a, b = ds.scene_tensors(default), ds.scene_tensors(cpu)
    assert a.keys() == b.keys()
    for name in a:
        assert torch.equal(a[name], b[name]), name
    for oa, ob in zip(default.objects, cpu.objects):      # learned box corrections, baked into the poses
        assert (oa.track.scene_T_box == ob.track.scene_T_box).all()


@no_cuda
def test_cuda_without_a_gpu_is_one_line_naming_the_knob(tiny_scene, capsys, tmp_path):
    with pytest.raises(DeviceUnavailable) as e:
        reconstruct(tiny_scene, ds.tiny_recon_config(device="cuda"), progress=False)
    msg = str(e.value)
    assert "\n" not in msg
    assert msg.startswith("ReconConfig.device='cuda' needs a CUDA GPU and the gsplat package")
    assert WHY_NOT in msg
    with pytest.raises(ValueError, match=r"ReconConfig.device must be one of \('auto', 'cpu', 'cuda'\)"):
        ReconConfig(device="gpu")
    assert resolve_device("auto") == resolve_device("cpu") == torch.device("cpu")

    # the command line: one line, exit code 2, before any log is read
    code = main(["convert", "av2", str(tmp_path / "nowhere"), str(tmp_path / "out"), "--mode", "render",
                 "--device", "cuda", "--no-progress"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "\n" not in err
    assert err.startswith("nuav2 convert: --device cuda needs a CUDA GPU and the gsplat package")
    native = ["--mode", "native", "--device", "cpu"]
    assert main(["convert", "av2", str(tmp_path), str(tmp_path / "o"), *native]) == 2
    assert "--device applies to --mode render only" in capsys.readouterr().err


def test_convert_device_option_is_checked_and_not_in_the_fingerprint():
    with pytest.raises(ConvertError, match=r"--device must be one of"):
        ConvertOptions(mode="render", device="tpu").check()
    ConvertOptions(mode="render", device="cuda", executor="ray").check()  # the cluster's GPUs decide (below)
    fingerprints = {ConvertOptions(mode="render", device=d).fingerprint() for d in ("auto", "cpu", "cuda")}
    assert len(fingerprints) == 1


def test_the_convert_report_names_the_device_each_render_log_used(render_db):
    report = json.loads((render_db / "convert_report.json").read_text())
    assert report["converted"]
    for summary in report["logs"].values():
        assert summary["mode"] == "render"
        assert summary["device"] == ("cuda:0" if CUDA else "cpu")


def test_ray_render_tasks_use_the_gpu_they_were_given():
    from nuav2.executors.ray_tasks import task_device, task_resources

    assert task_device("auto", []) == "cpu"          # no GPU given: never touch the node's GPUs
    assert task_device("cpu", [0]) == "cpu"
    with pytest.raises(DeviceUnavailable, match=r"^--device cuda: this Ray task was given no GPU"):
        task_device("cuda", [])
    if not CUDA:
        assert task_device("auto", [3], visible="3") == "cpu"   # given a GPU, but no CUDA/gsplat here
        with pytest.raises(DeviceUnavailable, match=r"^--device cuda:0 needs a CUDA GPU"):
            task_device("cuda", [3], visible="3")

    gpu_cluster = {"CPU": 64.0, "GPU": 8.0}
    cpu_cluster = {"CPU": 64.0}
    res = task_resources(gpu_cluster, ConvertOptions(mode="render", executor="ray", device="cpu"))
    assert res["num_gpus"] == 0.0                    # --device cpu reserves no GPU that would sit idle
    cuda = ConvertOptions(mode="render", executor="ray", device="cuda")
    assert task_resources(gpu_cluster, cuda)["num_gpus"] == 1
    with pytest.raises(ConvertError, match=r"^--device cuda: render tasks need a GPU each, .* has 0 GPU"):
        task_resources(cpu_cluster, cuda)


_RETAG_AS_CUDA = """
import sys, torch
# what torch.save writes for tensors on a GPU: every storage tagged cuda:0
torch.serialization.register_package(0, lambda s: "cuda:0" if s.device.type == "cpu" else None,
                                     lambda s, location: None)
torch.save(torch.load(sys.argv[1], map_location="cpu", weights_only=False), sys.argv[2])
"""


def test_a_checkpoint_written_on_a_gpu_resumes_on_the_cpu(tiny_scene, seeded, tmp_path):
    views, scene0, sky = seeded
    cfg = ds.tiny_train_config(iterations=8)

    def trainer() -> Trainer:
        return Trainer(ds.copy_scene(scene0), tiny_scene, views, sky, cfg)

    first = trainer()
    first.run(progress=False, checkpoint_dir=tmp_path, stop_at=4)
    cpu_file = tmp_path / CHECKPOINT_FILE
    state = torch.load(cpu_file, weights_only=False)           # no map_location needed: CPU tensors only
    assert all(t.device.type == "cpu" for t in _tensors(state))

    gpu_file = tmp_path / "written_on_gpu.pt"
    subprocess.run([sys.executable, "-c", _RETAG_AS_CUDA, str(cpu_file), str(gpu_file)], check=True)
    if not torch.cuda.is_available():
        with pytest.raises(RuntimeError, match="on a CUDA device"):
            torch.load(gpu_file, weights_only=False)           # really a GPU file: only map_location reads it

    resumed = {}
    for name, path in (("cpu", cpu_file), ("gpu", gpu_file)):
        t = trainer()
        t.load(path)
        assert t.step == 4 and t.splat.device == torch.device("cpu")
        t.run(progress=False)
        resumed[name] = t
    a, b = ds.scene_tensors(resumed["cpu"].splat), ds.scene_tensors(resumed["gpu"].splat)
    assert any(name.endswith("/pose_delta") for name in a), "objects with learned box corrections"
    for name in a:
        assert torch.equal(a[name], b[name]), name
    assert resumed["cpu"].losses == resumed["gpu"].losses


def _tensors(obj) -> list[torch.Tensor]:
    if isinstance(obj, torch.Tensor):
        return [obj]
    if isinstance(obj, dict):
        return [t for v in obj.values() for t in _tensors(v)]
    if isinstance(obj, (list, tuple)):
        return [t for v in obj for t in _tensors(v)]
    return []


def test_saved_scene_loads_onto_a_device(seeded, tmp_path):
    _, scene0, _ = seeded
    path = Path(tmp_path) / "scene.pt"
    scene0.save(path)
    from nuav2.splat.scene_model import SplatScene

    back = SplatScene.load(path, device="cpu")
    assert back.device == torch.device("cpu") and back.sky.texture.device == torch.device("cpu")
    assert torch.equal(back.background.means, scene0.background.means)


@no_cuda
def test_the_gpu_check_script_runs_its_cpu_part(tmp_path, capsys):
    """The GPU check only runs for real on a GPU machine; here its CPU half keeps it from rotting."""
    from nuav2.bench.gpu_check import main as gpu_check

    assert gpu_check([]) == 2 and "CUDA with gsplat is not usable here" in capsys.readouterr().err
    out = tmp_path / "gpu_check.json"
    assert gpu_check(["--dry-run", "--seconds", "0.2", "--iterations", "2", "--out", str(out)]) == 0
    result = json.loads(out.read_text())
    (run,) = result["reconstruction"]["runs"].values()
    assert run["device"] == "cpu" and run["iterations"] == 2 and run["target_psnr_db"] > 10
