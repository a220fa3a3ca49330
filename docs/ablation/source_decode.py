"""Source-image decoding at training size: the whole JPEG then an area resize, against a reduced JPEG
decode (`nuav2.image_decode.jpeg_reduction`), interleaved image by image, on full-resolution AV2-sized
images (a short synthetic log at --scale 1: 2048x1550 ring cameras). Prints one JSON line: ms per
image (wall and CPU, one OpenCV thread) for each, and the PSNR between their results.

    nuav2 synth --seed 0 --seconds 0.3 --scale 1 LOGS
    PYTHONPATH=. python docs/ablation/source_decode.py LOGS/train/<log_id> [--width 256]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time
from pathlib import Path

import cv2
import numpy as np

from converters.av2 import read_log
from nuav2.image_decode import jpeg_reduction, load_image_u8
from nuav2.splat.views import source_views


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("log_dir", type=Path)
    ap.add_argument("--width", type=int, default=256, help="training width in pixels (default 256)")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    cv2.setNumThreads(1)
    scene = read_log(args.log_dir)
    widest = max(c.width for c in scene.rig.cameras)
    views = source_views(scene, args.width / widest)
    clock = {"full": [0.0, 0.0], "reduced": [0.0, 0.0]}
    psnr = []
    for rep in range(args.repeats):
        for v in views:
            w, h = v.cam.width, v.cam.height
            out = {}
            for name, size in (("full", None), ("reduced", v.source_size)):
                c, t = time.process_time(), time.perf_counter()
                out[name] = load_image_u8(v.path, w, h, size)
                clock[name][0] += time.perf_counter() - t
                clock[name][1] += time.process_time() - c
            if rep == 0:
                mse = float(np.mean((out["full"].astype(np.float64) - out["reduced"]) ** 2))
                psnr.append(10 * math.log10(255**2 / max(mse, 1e-12)))
    n = args.repeats * len(views)
    print(json.dumps({
        "images": len(views), "source_size": sorted({v.source_size for v in views}),
        "train_size": sorted({(v.cam.width, v.cam.height) for v in views}),
        "factor": sorted({jpeg_reduction(v.path, v.source_size, v.cam.width, v.cam.height) for v in views}),
        **{f"{k}_ms_wall": round(1000 * c[0] / n, 2) for k, c in clock.items()},
        **{f"{k}_ms_cpu": round(1000 * c[1] / n, 2) for k, c in clock.items()},
        "psnr_db_min": round(min(psnr), 1), "psnr_db_mean": round(float(np.mean(psnr)), 1),
        "load_1min": round(os.getloadavg()[0], 2)}))


if __name__ == "__main__":
    main()
