"""Wall and CPU seconds of one warp conversion of a saved log, for comparing code versions.

Run it once per checkout, alternating them, on the same log (numba on one thread); the first
conversion of a process includes loading the compiled kernels and is reported apart. Usage:

    nuav2 synth --seed 0 --preset hard --seconds 15 --scale 0.125 LOGS
    NUMBA_NUM_THREADS=1 PYTHONPATH=CHECKOUT python docs/ablation/warp_cpu.py LOGS/train/<log_id> --reps 0
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path

from nuav2.convert import ConvertOptions, convert_av2


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("log_dir", type=Path, help="an AV2 log folder")
    ap.add_argument("--reps", type=int, default=2, help="conversions after the first (default 2)")
    args = ap.parse_args()
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(args.reps + 1):
            out = Path(tmp) / "out"
            shutil.rmtree(out, ignore_errors=True)
            wall0, cpu0 = time.perf_counter(), time.process_time()
            convert_av2(args.log_dir, out, ConvertOptions(mode="warp", rig="nuscenes", scale=0.125,
                                                          show_progress=False))
            runs.append((round(time.perf_counter() - wall0, 2), round(time.process_time() - cpu0, 2)))
    print(f"first (wall s, CPU s) {runs[0]}; then {runs[1:]}")


if __name__ == "__main__":
    main()
