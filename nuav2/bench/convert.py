"""Benchmark: native conversion throughput (frames/s) against a bare av2-loader read of the same frames.

A frame is one LiDAR sweep or one camera image. The baseline, run in the same process on the
same synthetic log, is what any consumer of AV2 pays at least: ``AV2SensorDataLoader`` file
lookup, reading every sweep (``read_lidar_sweep``) and decoding every image (``read_img``).
The conversion is timed end to end (read the log, write tables, LIDAR_TOP, images, map, merge).
The two sides alternate, ``repeats`` times each, and each keeps its fastest run (wall and CPU seconds
apart), so first-call costs stay out; the load is sampled after every run.
"""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

from nuav2.bench.timing import Stopwatch
from nuav2.convert import ConvertOptions, convert_av2


def _av2_read(split_dir: Path) -> int:
    """Read every sweep and decode every image of every log through the av2 loader; returns frames read."""
    from av2.datasets.sensor.av2_sensor_dataloader import AV2SensorDataLoader
    from av2.datasets.sensor.constants import RingCameras, StereoCameras
    from av2.utils.io import read_img, read_lidar_sweep

    loader = AV2SensorDataLoader(data_dir=split_dir, labels_dir=split_dir)
    cams = [c.value for c in RingCameras] + [c.value for c in StereoCameras]
    frames = 0
    for log_id in loader.get_log_ids():
        for fpath in loader.get_ordered_log_lidar_fpaths(log_id):
            read_lidar_sweep(fpath, attrib_spec="xyz")  # reads the whole feather file
            frames += 1
        for cam in cams:
            for fpath in loader.get_ordered_log_cam_fpaths(log_id, cam):
                read_img(fpath)
                frames += 1
    return frames


def bench_convert(seconds: float = 3.0, image_scale: float = 0.25, image_link: str = "copy",
                  keyframe_hz: float | None = None, repeats: int = 2, seed: int = 0,
                  workdir: Path | None = None) -> dict:
    """Generate one synthetic log, then time the av2 read and the native conversion of it."""
    from nuav2.synth import SynthConfig, generate_log

    tmp = Path(tempfile.mkdtemp(prefix="nuav2-bench-convert-", dir=workdir))
    try:
        config = SynthConfig(seconds=seconds, image_scale=image_scale)
        log_dir = generate_log(tmp / "av2", seed=seed, config=config)
        split_dir = log_dir.parent
        options = ConvertOptions(image_link=image_link, keyframe_hz=keyframe_hz, show_progress=False)
        read_sw, convert_sw = Stopwatch(), Stopwatch()
        frames, report = 0, None
        for k in range(repeats):  # interleaved: each repeat reads, then converts
            with read_sw:
                frames = _av2_read(split_dir)
            with convert_sw:
                report = convert_av2(split_dir, tmp / f"out{k}", options)
        assert report is not None
        written = report.table_counts["sample_data"]
        if written != frames:
            raise RuntimeError(f"conversion wrote {written} sample_data but the av2 read saw {frames} frames")
        read_s, convert_s = min(read_sw.wall_s), min(convert_sw.wall_s)
        fps, read_fps = frames / convert_s, frames / read_s
        return {
            "frames": frames, "samples": report.table_counts["sample"], "frames_per_s": fps,
            "av2_read_frames_per_s": read_fps, "ratio_vs_av2_read": fps / read_fps,
            "convert_s": convert_s, "av2_read_s": read_s,
            "convert_cpu_s": min(convert_sw.cpu_s), "av2_read_cpu_s": min(read_sw.cpu_s),
            "ratio_vs_av2_read_cpu": min(read_sw.cpu_s) / max(min(convert_sw.cpu_s), 1e-9),
            "load_1min": [round(x, 2) for x in (*read_sw.load, *convert_sw.load)],
            "image_link": image_link,
            "keyframe_hz": keyframe_hz, "repeats": repeats, "synthetic_config": config.to_dict(),
        }
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
