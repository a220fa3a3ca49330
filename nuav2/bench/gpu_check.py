"""One-shot GPU check for render mode (issue 14): the CUDA tests, then one log reconstructed on cuda and cpu.

    python -m nuav2.bench.gpu_check --out gpu_check.json          # on a machine with CUDA + gsplat

Steps, each timed: (1) the environment (torch, CUDA, gsplat) and a first gsplat render, which
includes gsplat's one-time CUDA compile where its extension is not prebuilt; (2) ``pytest`` on
the CUDA tests (tests/test_raster_gsplat_parity.py, tests/test_recon_cuda.py); (3) a synthetic
log (default 2 s, the benchmark's default log) reconstructed with the ``fast`` preset on each
device, scored in the nuScenes rig against the world's truth (PSNR) with wall seconds. On an H100
with 16 cores it took 2.5 minutes after gsplat's 76 s compile (tests 76 s, the 2 s log on both
devices 62 s; docs/ablation/gpu_check_h100.json). ``--dry-run`` runs what a CPU-only
machine can (the CPU reconstruction, tiny with ``--seconds``/``--iterations``) to check the script.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from nuav2.cli_types import path

CUDA_TESTS = ("tests/test_raster_gsplat_parity.py", "tests/test_recon_cuda.py")


def environment() -> dict:
    """Versions and what the device switch sees."""
    import torch

    from nuav2.splat.gsplat_backend import gsplat_available

    ok, why = gsplat_available()
    env = {"python": sys.version.split()[0], "torch": torch.__version__, "torch_cuda": torch.version.cuda,
           "cuda_available": torch.cuda.is_available(), "gsplat_usable": ok, "why_not": why or None}
    try:
        import gsplat

        env["gsplat"] = gsplat.__version__
    except ImportError:
        env["gsplat"] = None
    if torch.cuda.is_available():
        env["gpu"] = torch.cuda.get_device_name(0)
    return env


def first_gsplat_render_s() -> float:
    """Seconds of the first gsplat render (includes loading or JIT-compiling its CUDA extension)."""
    import torch

    from nuav2.splat import rasterize

    t0 = time.perf_counter()
    g = torch.Generator().manual_seed(0)
    n = 1000
    means = (torch.rand(n, 3, generator=g) - 0.5) * 4 + torch.tensor([0.0, 0.0, 6.0])
    quats = torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(n, 1)
    params = (means, quats, torch.full((n, 3), -2.5), torch.zeros(n), torch.rand(n, 3, generator=g))
    args = [t.cuda() for t in params]
    K = [[60.0, 0.0, 32.5], [0.0, 60.0, 24.5], [0.0, 0.0, 1.0]]
    out = rasterize(*args, torch.eye(4).numpy(), K, 64, 48, backend="gsplat")
    torch.cuda.synchronize()
    assert out.meta["backend"] == "gsplat" and float(out.alpha.max()) > 0
    return time.perf_counter() - t0


def run_tests(timeout_s: float) -> dict:
    """``pytest`` on the CUDA tests in a subprocess: return code, seconds, the summary lines."""
    t0 = time.perf_counter()
    cmd = [sys.executable, "-m", "pytest", "-q", "-rs", "-p", "no:cacheprovider", *CUDA_TESTS]
    try:
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s)
        rc, text = done.returncode, done.stdout + done.stderr
    except subprocess.TimeoutExpired as e:
        out = e.stdout or b""
        rc, text = "timeout", out.decode(errors="replace") if isinstance(out, bytes) else out
    return {"returncode": rc, "seconds": round(time.perf_counter() - t0, 1),
            "tail": text.strip().splitlines()[-15:]}


def reconstruct_on(devices: list[str], seconds: float, iterations: int | None, workdir: Path) -> dict:
    """One synthetic log reconstructed (``fast`` preset) on each device: wall seconds and target-rig PSNR."""
    from dataclasses import replace

    from converters.av2 import read_log
    from nuav2.bench.recon import target_rig_scores
    from nuav2.recon import ReconConfig, reconstruct
    from nuav2.synth import SynthConfig, generate_log, load_world

    t0 = time.perf_counter()
    log_dir = generate_log(workdir, seed=0, config=SynthConfig(seconds=seconds))
    scene, world = read_log(log_dir), load_world(log_dir)
    out = {"log_seconds": seconds, "generate_s": round(time.perf_counter() - t0, 1), "runs": {}}
    for device in devices:
        cfg = replace(ReconConfig.fast(), device=device)
        if iterations is not None:
            cfg = cfg.with_iterations(iterations)
        t0 = time.perf_counter()
        splat = reconstruct(scene, cfg, progress=False)
        recon_s = time.perf_counter() - t0
        scores = target_rig_scores(splat, scene, world, paint=False)
        train = splat.info["train"]
        out["runs"][device] = {
            "device": splat.info["device"],
            "recon_wall_s": round(recon_s, 1),
            "train_s": round(train["seconds"], 1),
            "iterations": train["steps"],
            "gaussians": splat.num_gaussians(),
            "target_psnr_db": round(scores["psnr_db"], 3),
            "target_ssim": round(scores["ssim"], 4),
        }
    return out


def print_table(runs: dict) -> None:
    cols = ("device", "recon_wall_s", "train_s", "iterations", "gaussians", "target_psnr_db", "target_ssim")
    print("| " + " | ".join(cols) + " |")
    print("|" + "---|" * len(cols))
    for r in runs.values():
        print("| " + " | ".join(str(r[c]) for c in cols) + " |", flush=True)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m nuav2.bench.gpu_check", description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=path, default=None, help="write the results as JSON here too")
    p.add_argument("--seconds", type=float, default=2.0, help="synthetic log length (default: %(default)s)")
    p.add_argument("--iterations", type=int, default=None, help="override the fast preset's 600 iterations")
    p.add_argument("--tests-timeout", type=float, default=150.0, help="seconds for the pytest step")
    p.add_argument("--dry-run", action="store_true",
                   help="no CUDA needed: skip the CUDA steps, run the CPU one")
    args = p.parse_args(argv)

    result: dict = {"environment": environment()}
    print(json.dumps(result["environment"]), flush=True)
    usable = result["environment"]["gsplat_usable"]
    if not usable and not args.dry_run:
        why = result["environment"]["why_not"]
        print(f"gpu_check: CUDA with gsplat is not usable here ({why})", file=sys.stderr)
        return 2
    if usable:
        result["first_gsplat_render_s"] = round(first_gsplat_render_s(), 1)
        print(f"first gsplat render (incl. compile/load): {result['first_gsplat_render_s']} s", flush=True)
        result["tests"] = run_tests(args.tests_timeout)
        print("\n".join(result["tests"]["tail"]), flush=True)
    devices = ["cuda", "cpu"] if usable else ["cpu"]
    with tempfile.TemporaryDirectory() as tmp:
        result["reconstruction"] = reconstruct_on(devices, args.seconds, args.iterations, Path(tmp))
    runs = result["reconstruction"]["runs"]
    print_table(runs)
    if len(runs) == 2:
        diff = runs["cuda"]["target_psnr_db"] - runs["cpu"]["target_psnr_db"]
        result["psnr_cuda_minus_cpu_db"] = round(diff, 3)
        print(f"PSNR cuda - cpu: {result['psnr_cuda_minus_cpu_db']} dB", flush=True)
    if args.out is not None:
        args.out.write_text(json.dumps(result, indent=1))
    tests_ok = not usable or result["tests"]["returncode"] == 0
    close = len(runs) < 2 or abs(result["psnr_cuda_minus_cpu_db"]) < 0.5
    return 0 if tests_ok and close else 1


if __name__ == "__main__":
    sys.exit(main())
