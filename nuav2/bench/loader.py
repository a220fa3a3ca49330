"""Benchmark: MapTR-style loader throughput (samples/s, GT extraction included) against a bare read.

The baseline, run in the same process over the same keyframes, is what any loader must do at
least: look the camera files up through the devkit and decode the JPEGs. The ratio says what
the pose bookkeeping, vectorized-map GT and fixed-point targets cost on top of that. Building
each location's map index (once per map) is timed separately.
"""

from __future__ import annotations

import contextlib
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

from nuav2.bench.timing import Stopwatch
from nuav2.maptr.dataset import MapSampleDataset, load_image_rgb
from nuav2.maptr.infos import camera_channels
from nuav2.maptr.subsets import available_splits


def _bare_read(ds: MapSampleDataset, index: int) -> None:
    nusc = ds.nusc
    sample = nusc.get("sample", ds.items[index][0])
    for ch in camera_channels(nusc, sample, ds.cameras):
        load_image_rgb(nusc.get_sample_data_path(sample["data"][ch]))


def bench_loader(
    dataroot: str | Path,
    version: str,
    split: str | None = None,
    max_samples: int = 50,
    image_scale: float = 1.0,
) -> dict:
    """Throughput of ``MapSampleDataset.__getitem__`` vs the bare camera read of ``max_samples`` keyframes."""
    from nuscenes.nuscenes import NuScenes

    nusc = NuScenes(version=version, dataroot=str(dataroot), verbose=False)
    split = split or available_splits(nusc)[0]
    ds = MapSampleDataset(dataroot, version, split, image_scale=image_scale, nusc=nusc)
    n = min(len(ds), max_samples)
    if n == 0:
        raise ValueError(f"{dataroot}/{version}: split {split!r} has no keyframes to benchmark")
    t0 = time.perf_counter()
    locations = sorted({ds.info(i)["map_location"] for i in range(n)})
    for loc in locations:
        ds.gt.vectorizer(loc)
    map_build_s = time.perf_counter() - t0
    (
        _bare_read(ds, 0),
        ds.vectors(0),
        ds[0],
    )  # warm-up: lazy imports and first-call caches stay out of the rates

    # interleaved per sample, so a load change on the shared machine hits every candidate alike
    bare_sw, gt_sw, full_sw = Stopwatch(), Stopwatch(), Stopwatch()
    n_vectors = n_cams = 0
    for i in range(n):
        with bare_sw:
            _bare_read(ds, i)
        with gt_sw:
            n_vectors += len(ds.vectors(i))
        with full_sw:
            n_cams = len(ds[i]["cam_names"])
    bare_s, gt_s, full_s = sum(bare_sw.wall_s), sum(gt_sw.wall_s), sum(full_sw.wall_s)
    return {
        "dataroot": str(dataroot),
        "version": version,
        "split": split,
        "samples": n,
        "cameras": n_cams,
        "locations": len(locations),
        "map_build_s": round(map_build_s, 4),
        "vectors_per_sample": round(n_vectors / n, 2),
        "samples_per_s": round(n / full_s, 3),
        "gt_only_samples_per_s": round(n / gt_s, 3),
        "bare_read_samples_per_s": round(n / bare_s, 3),
        "ratio_vs_bare_read": round(bare_s / full_s, 4),
        "cpu_s": {"bare_read": round(sum(bare_sw.cpu_s), 4), "gt_only": round(sum(gt_sw.cpu_s), 4),
                  "full": round(sum(full_sw.cpu_s), 4)},
        "wall_s": {"bare_read": round(bare_s, 4), "gt_only": round(gt_s, 4), "full": round(full_s, 4)},
        "load_1min": [round(min(full_sw.load), 2), round(max(full_sw.load), 2)],
    }


@contextlib.contextmanager
def synthetic_dataroot(
    seconds: float = 2.0,
    image_scale: float = 0.125,
    version: str = "v1.0-nuav2",
) -> Iterator[Path]:
    """A temporary nuAV2 dataroot: one synthetic AV2 log converted in native mode (removed afterwards)."""
    from nuav2.convert import ConvertOptions, convert_av2
    from nuav2.synth import SynthConfig, generate_log

    with tempfile.TemporaryDirectory(prefix="nuav2_bench_loader_") as tmp:
        log_dir = generate_log(
            Path(tmp) / "av2", seed=0, config=SynthConfig(seconds=seconds, image_scale=image_scale)
        )
        convert_av2(log_dir, Path(tmp) / "db", ConvertOptions(version=version, show_progress=False))
        yield Path(tmp) / "db"
