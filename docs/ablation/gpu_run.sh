#!/bin/bash
# GPU check of render mode (issue 14), run from the repository root on a CUDA machine with PyTorch:
# gsplat's CUDA compile, `python -m nuav2.bench.gpu_check` (the CUDA tests + a 2 s log on cuda and cpu),
# then a 15 s log with the `default` preset on cuda. Results go to $OUT (default ./gpu_out).
# .whl/ holds the packages the machine lacks, as cp312 wheels (pip download --no-deps --only-binary=:all:
# --python-version 3.12 ...): gsplat==1.5.3 av2==0.3.6 shapely==2.0.7 pyproj==3.7.2 universal_pathlib==0.3.10
# pathlib_abc==0.5.2. BUDGET (default 520) is the seconds the whole script may take; the last step gets what is left.
OUT=${OUT:-gpu_out}; mkdir -p "$OUT"
START=$(date +%s); DEADLINE=$((START + ${BUDGET:-520}))
left() { echo $((DEADLINE - $(date +%s))); }
export PYTHONUNBUFFERED=1 MAX_JOBS=16 TORCH_CUDA_ARCH_LIST=9.0
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl > /tmp/pip.log 2>&1 || { echo pip failed; cat /tmp/pip.log; exit 1; }
export PYTHONPATH=/tmp/site:$PWD
{ nvidia-smi -L; nproc; python3 -c "import sys,numpy,torch,numba;print(sys.version, numpy.__version__, torch.__version__, torch.version.cuda, numba.__version__)"; nvcc --version | tail -2; } > $OUT/env.txt 2>&1
cat $OUT/env.txt
( python3 -m nuav2 synth /tmp/g15 --seed 0 --preset easy --seconds 15 > $OUT/synth15.log 2>&1 ) &
SYN=$!
echo "[$(left) s left] compiling gsplat"
python3 -c "
import time; t=time.time()
from gsplat.cuda._backend import _C
print('gsplat compile+load s', round(time.time()-t,1), 'ok', _C is not None)" > $OUT/compile.log 2>&1
tail -5 $OUT/compile.log
echo "[$(left) s left] gpu_check"
timeout $(( $(left) - 20 )) python3 -m nuav2.bench.gpu_check --tests-timeout 170 --out $OUT/gpu_check.json > $OUT/gpu_check.log 2>&1
echo "gpu_check rc=$?"; tail -25 $OUT/gpu_check.log
wait $SYN; tail -c 400 $OUT/synth15.log
L=$(ls -d /tmp/g15/train/*/ | head -1)
echo "[$(left) s left] 15 s default preset on cuda: $L"
timeout $(( $(left) - 5 )) python3 docs/ablation/recon_long_log.py $L --preset default --device cuda > $OUT/long15_cuda.json 2> $OUT/long15_cuda.err
echo "long15 rc=$?"; cat $OUT/long15_cuda.json; tail -3 $OUT/long15_cuda.err
echo "[$(left) s left] done"
