"""Wall and CPU seconds of one warp conversion of a saved log, for comparing code versions.

Run it once per checkout, alternating them, on the same log (numba on one thread); the first
conversion of a process includes loading the compiled kernels and is reported apart. Each run
also prints a hash of every written image and table, so versions that should write the same bytes
can be seen to. ``--threads 1`` keeps a log on one thread where the code would give it two
(``nuav2.convert.log_threads``; code older than that ignores it). Usage:

    nuav2 synth --seed 0 --preset hard --seconds 15 --scale 0.125 LOGS
    NUMBA_NUM_THREADS=1 PYTHONPATH=CHECKOUT python docs/ablation/warp_cpu.py LOGS/train/<log_id> --reps 0
"""

from __future__ import annotations

import argparse
import hashlib
import os
import shutil
import tempfile
import time
from pathlib import Path

import nuav2.convert
from nuav2.convert import ConvertOptions, convert_av2


def written_hash(out: Path) -> str:
    """sha256 (12 hex) over the paths and bytes of the images and tables (not the timed report)."""
    h = hashlib.sha256()
    for p in sorted(out.rglob("*")):
        if p.is_file() and p.suffix in (".jpg", ".json") and p.name != "convert_report.json":
            h.update(p.relative_to(out).as_posix().encode())
            h.update(p.read_bytes())
    return h.hexdigest()[:12]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("log_dir", type=Path, help="an AV2 log folder")
    ap.add_argument("--reps", type=int, default=2, help="conversions after the first (default 2)")
    ap.add_argument("--threads", type=int, choices=(1,), help="1: one thread per log whatever the cores")
    args = ap.parse_args()
    if args.threads == 1 and hasattr(nuav2.convert, "log_threads"):
        nuav2.convert.log_threads = lambda options: 1
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(args.reps + 1):
            out = Path(tmp) / "out"
            shutil.rmtree(out, ignore_errors=True)
            wall0, cpu0 = time.perf_counter(), time.process_time()
            convert_av2(args.log_dir, out, ConvertOptions(mode="warp", rig="nuscenes", scale=0.125,
                                                          show_progress=False))
            runs.append((round(time.perf_counter() - wall0, 2), round(time.process_time() - cpu0, 2),
                         written_hash(out)))
    print(f"first (wall s, CPU s, hash) {runs[0]}; then {runs[1:]}; load {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
