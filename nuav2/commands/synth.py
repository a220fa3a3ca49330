"""``nuav2 synth OUT_DIR --preset hard --seed N``: write a procedural AV2 sensor log (demo and test data)."""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

from nuav2.cli_types import path


def _dir_size(path: Path) -> tuple[int, int]:
    files = [p for p in path.rglob("*") if p.is_file()]
    return len(files), sum(p.stat().st_size for p in files)


def run(args: argparse.Namespace) -> int:
    from nuav2.synth import SynthConfig, build_world, generate_log

    overrides = {"seconds": args.seconds, "image_scale": args.scale, "include_stereo": args.stereo,
                 "layout": args.layout}
    if args.lidar_azimuth_steps is not None:
        overrides["lidar_azimuth_steps"] = args.lidar_azimuth_steps
    config = SynthConfig.for_preset(args.preset, **overrides)  # a bad value: one line from nuav2.cli
    t0, cpu0 = time.perf_counter(), time.process_time()
    world = build_world(args.seed, config)
    _ = world.texture.packed  # the ground texture, built once per world
    t1, cpu1 = time.perf_counter(), time.process_time()
    log_dir = generate_log(args.out_dir, seed=args.seed, config=config, split=args.split, progress=True)
    t2, cpu2 = time.perf_counter(), time.process_time()
    n_files, n_bytes = _dir_size(log_dir)
    n = config.n_sweeps
    print(json.dumps({
        "log_dir": str(log_dir), "split_dir": str(log_dir.parent), "seed": args.seed, "preset": args.preset,
        "layout": world.layout_name, "manoeuvre": world.manoeuvre, "factors": sorted(config.factors),
        "frames": n, "cameras_per_frame": 7 + (2 if args.stereo else 0),
        "files": n_files, "megabytes": round(n_bytes / 1e6, 2), "seconds": round(t2 - t0, 2),
        "seconds_per_frame": round((t2 - t0) / n, 4), "cpu_seconds_per_frame": round((cpu2 - cpu0) / n, 4),
        "world_setup_seconds": round(t1 - t0, 2), "world_setup_cpu_seconds": round(cpu1 - cpu0, 2),
        "frame_seconds": round((t2 - t1) / n, 4), "frame_cpu_seconds": round((cpu2 - cpu1) / n, 4),
        "load_1min": round(os.getloadavg()[0], 2),
    }))
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    from nuav2.bench.cli_args import lidar_azimuth_steps, synth_image_scale, synth_seconds
    from nuav2.cli_types import non_negative_int
    from nuav2.synth import LAYOUTS, PRESETS

    p = subparsers.add_parser(
        "synth", help="write a synthetic AV2 sensor log (procedural streets, exact ground truth)",
        description="Generate a deterministic AV2-format log OUT_DIR/<split>/<log_id>/ (poses, lidar, ring "
                    "camera JPEGs, cuboids, map, ground height) from a procedural world; the same seed "
                    "and options give byte-identical files. --preset picks the realism (easy: flat "
                    "intersection, ideal sensors; medium: relief, varied layouts and manoeuvres, shaped "
                    "content, noisy lidar and labels; hard: also shadows, sky and camera exposure; see "
                    "docs/realism.md). Prints a JSON summary with the wall and CPU time per frame (one 10 Hz "
                    "sweep plus its 20 Hz camera images), with and without building the world.")
    p.add_argument("out_dir", type=path, help="dataset root; the log goes to OUT_DIR/<split>/<log_id>/")
    p.add_argument("--seed", type=non_negative_int, default=0,
                   help="world seed (>= 0): layout, actors, offsets, timestamps (default: %(default)s)")
    p.add_argument("--preset", choices=PRESETS, default="easy", help="realism preset (default: easy)")
    p.add_argument("--layout", choices=LAYOUTS, default=None,
                   help="road layout (default: four_way, or drawn from the seed when layouts vary)")
    p.add_argument("--seconds", type=synth_seconds, default=2.0,
                   help="driving time, > 0.05 (10 sweeps per second; default: %(default)s)")
    p.add_argument("--scale", type=synth_image_scale, default=0.125,
                   help="camera resolution factor of the AV2 rig, > 0 (default: %(default)s)")
    p.add_argument("--split", default="train", choices=("train", "val", "test"),
                   help="AV2 split folder (default: %(default)s)")
    p.add_argument("--stereo", action="store_true", help="also write the two stereo_front cameras")
    p.add_argument("--lidar-azimuth-steps", type=lidar_azimuth_steps, default=None,
                   help="rays per beam per sweep, >= 8 (default 512: ~28k points)")
    p.set_defaults(func=run)
