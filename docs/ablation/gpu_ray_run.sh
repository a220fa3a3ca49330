#!/bin/bash
# The Ray executor on a GPU (issue 14), run from the repository root on a CUDA machine with PyTorch.
# Two synthetic 2 s logs are converted in render mode by `convert --executor ray` on a local Ray
# instance that sees the machine's GPU, both tasks at once with half a GPU each (--gpus-per-task 0.5),
# so they also race for gsplat's first CUDA build (the per-machine lock in nuav2/machine_lock.py);
# then the same logs with the local executor on the same GPU, to compare. Results go to $OUT
# (default ./gpu_out): both convert_report.json files, the table hashes, Ray's logs when it fails.
# .whl/ holds what the machine lacks: cp312 wheels of gsplat==1.5.3 shapely==2.0.7 pyproj==3.7.2
# universal_pathlib==0.3.10 pathlib_abc==0.5.2 pyquaternion jsonschema jsonschema-specifications
# referencing rpds-py (pip download --no-deps --only-binary=:all: --python-version 3.12 ...), and two
# tarballs, because Ray's wheel alone is over the 64 MiB that travels to the lent machine:
#   av2.tar.xz: av2==0.3.6's wheel unzipped without av2/_r*.so (only av2's torch loaders use it)
#   ray.tar.xz: ray==2.60.0's wheel unzipped, then rm -rf ray/{jars,rllib,tune,train,serve,data,llm}
#     ray/dashboard/client/build, find -name '*.map' -delete, strip --strip-unneeded ray/_raylet.so
#     ray/core/src/ray/raylet/raylet ray/core/src/ray/gcs/gcs_server, tar -cJf (25 MB)
# DEVICE=cpu GPUS=0 NO_INSTALL=1 PY=.venv/bin/python runs the same steps on a CPU machine to check
# the script; CUDA_TESTS=SECONDS also runs the CUDA tests at the end. On the H100 (2026-11-26) its Ray
# step failed before the whole-number CPU fix of nuav2/executors/ray_tasks.py (see docs/cluster.md);
# on 2026-11-27 it ran to its end there (docs/ablation/gpu_ray_h100_full.json).
OUT=${OUT:-gpu_out}; mkdir -p "$OUT"
DEVICE=${DEVICE:-cuda}; GPUS=${GPUS:-0.5}; PY=${PY:-python3}
export PYTHONUNBUFFERED=1 MAX_JOBS=16 TORCH_CUDA_ARCH_LIST=9.0
START=$(date +%s); t() { echo "[$(( $(date +%s) - START )) s]"; }
if [ -d .whl ] && [ -z "$NO_INSTALL" ]; then
  mkdir -p /tmp/site
  $PY -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl \
    > /tmp/pip.log 2>&1 || { echo pip failed; cat /tmp/pip.log; exit 1; }
  for a in .whl/*.tar.xz; do tar -xJf "$a" -C /tmp/site || exit 1; done
  export PYTHONPATH=/tmp/site:$PWD
fi
{ nvidia-smi -L; nproc; $PY -c "import sys,numpy,torch,ray;print(sys.version.split()[0], numpy.__version__, torch.__version__, torch.version.cuda, ray.__version__)"; } > "$OUT/env.txt" 2>&1
cat "$OUT/env.txt"; t
rm -rf /tmp/glogs /tmp/gout_ray /tmp/gout_local
$PY -m nuav2 synth /tmp/glogs --seed 0 --seconds 2 --scale 0.25 > /tmp/synth0.log 2>&1 &
$PY -m nuav2 synth /tmp/glogs --seed 1 --seconds 2 --scale 0.25 --layout t_junction > /tmp/synth1.log 2>&1
wait; ls /tmp/glogs/train; t
convert() {  # OUT_DIR, extra flags...
  local dst=$1; shift
  timeout "${CONVERT_TIMEOUT:-240}" $PY -m nuav2 convert av2 /tmp/glogs/train "$dst" --mode render --scale 0.25 --recon-preset fast \
    --device "$DEVICE" --no-progress "$@" > "$OUT/$(basename "$dst").log" 2>&1
  local rc=$?; echo "convert $dst rc=$rc"; tail -4 "$OUT/$(basename "$dst").log"; t
  cp "$dst/convert_report.json" "$OUT/$(basename "$dst")_report.json" 2>/dev/null
}
convert /tmp/gout_ray --executor ray --workers 2 --cpus-per-task 4 --gpus-per-task "$GPUS"

if [ ! -f /tmp/gout_ray/convert_report.json ] && [ -d /tmp/ray/session_latest/logs ]; then
  tar -czhf "$OUT/ray_logs.tgz" -C /tmp/ray/session_latest logs; echo "Ray logs in ray_logs.tgz"
  for f in raylet.out raylet.err gcs_server.out dashboard_agent.log runtime_env_agent.log; do
    echo "== $f"; tail -n 15 "/tmp/ray/session_latest/logs/$f" 2>/dev/null | cut -c1-300; done
fi
convert /tmp/gout_local --workers 1
$PY - "$OUT" <<'EOF'
import hashlib, json, sys
from pathlib import Path
out = Path(sys.argv[1]); summary, hashes = {}, {}
for name in ("gout_ray", "gout_local"):
    root = Path("/tmp") / name
    report = json.loads((root / "convert_report.json").read_text()) if (root / "convert_report.json").exists() else {}
    tables = {p.name: hashlib.sha256(p.read_bytes()).hexdigest()[:12] for p in sorted(root.glob("v1.0-*/*.json"))}
    images = {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()[:12]
              for p in sorted(root.glob("samples/CAM_*/*.jpg"))}
    summary[name] = {"report": report, "tables": tables, "images": len(images)}
    hashes[name] = images
a, b = summary["gout_ray"]["tables"], summary["gout_local"]["tables"]
summary["tables_differ"] = sorted(k for k in a.keys() | b.keys() if a.get(k) != b.get(k))
a, b = hashes["gout_ray"], hashes["gout_local"]
summary["images_differ"] = sum(a.get(k) != b.get(k) for k in a.keys() | b.keys())
# How far apart the two runs' images are (GPU runs differ in float rounding and atomics' order).
import numpy as np
from PIL import Image
psnr = []
for k in sorted(a.keys() & b.keys()):
    x, y = (np.asarray(Image.open(Path("/tmp") / n / k), dtype=np.float64) for n in ("gout_ray", "gout_local"))
    mse = float(np.mean((x - y) ** 2))
    psnr.append(99.0 if mse == 0 else 10 * np.log10(255.0**2 / mse))
if psnr:
    summary["ray_vs_local_psnr_db"] = {"min": round(min(psnr), 2), "median": round(float(np.median(psnr)), 2),
                                       "images": len(psnr)}
qa, qb = ({k: v for r in json.loads((Path("/tmp") / n / "v1.0-nuav2/nuav2_logs.json").read_text())
           for k, v in r.get("image_quality", {}).items()} for n in ("gout_ray", "gout_local"))
summary["image_quality_max_abs_diff"] = max((abs(qa[k] - qb[k]) for k in qa.keys() & qb.keys()), default=None)
(out / "gpu_ray_summary.json").write_text(json.dumps(summary, indent=1))
print(json.dumps({k: summary.get(k) for k in ("tables_differ", "images_differ", "ray_vs_local_psnr_db",
                                               "image_quality_max_abs_diff")}))
for name in ("gout_ray", "gout_local"):
    print(name, summary[name]["images"], "images", json.dumps(summary[name]["report"])[:1500])
EOF
t
if [ -n "$CUDA_TESTS" ]; then  # the CUDA tests on the same machine (gsplat already built above)
  timeout "$CUDA_TESTS" $PY -m pytest -q -p no:cacheprovider tests/test_raster_gsplat_parity.py tests/test_recon_cuda.py \
    > "$OUT/cuda_tests.log" 2>&1; echo "cuda tests rc=$?"; tail -5 "$OUT/cuda_tests.log"; t
fi
