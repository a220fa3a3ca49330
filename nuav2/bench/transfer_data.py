"""The benchmark's data: synthetic train / test worlds, their conversions, and geo-disjoint splits.

Every step reuses finished work, so an interrupted benchmark resumes: a world whose log directory
exists is not regenerated (logs appear atomically), and ``convert_av2`` reuses complete shards.

- ``worlds/train/<log>``: the training worlds (AV2 rig), ``worlds/val/<log>``: the test worlds.
- ``db/<set>/``: the training worlds converted per set: ``native`` (AV2 rig), ``warp`` and
  ``render`` (nuAV2 in the target rig); ``db/truth/`` holds train *and* test worlds rendered
  exactly in the target rig (the oracle's training set and everyone's test set).
- ``nuav2 split --lists`` writes ``geo_train`` / ``geo_test`` into every database from the world
  lists and reports the leakage (share of test keyframes within 5 m of a training keyframe).
"""

from __future__ import annotations

import contextlib
import io
import json
import logging
import os
import time
from dataclasses import dataclass
from pathlib import Path

from nuav2.atomic import atomic_write_json
from nuav2.bench.transfer_config import TransferConfig

log = logging.getLogger(__name__)

TRAIN_SPLIT, TEST_SPLIT = "geo_train", "geo_test"


@dataclass(frozen=True)
class WorldSpec:
    seed: int
    split: str  # AV2 split directory: "train" or "val" (the test worlds)
    layout: str
    city: str


def synth_config(cfg: TransferConfig, world: WorldSpec):
    """The SynthConfig of one world: the preset and layout, the benchmark's log length and cameras."""
    from nuav2.synth import SynthConfig

    return SynthConfig.for_preset(
        cfg.preset,
        layout=world.layout,
        seconds=cfg.seconds,
        image_scale=cfg.synth_image_scale,
        city=world.city,
    )


def world_specs(cfg: TransferConfig) -> list[WorldSpec]:
    """Train worlds then test worlds: distinct seeds, layouts cycling (test ones offset), two cities."""
    from nuav2.synth import LAYOUTS

    layouts = tuple(cfg.layouts) if cfg.layouts else LAYOUTS
    train = [
        WorldSpec(cfg.train_seed0 + i, "train", layouts[i % len(layouts)], cfg.train_city)
        for i in range(cfg.train_worlds)
    ]
    test = [
        WorldSpec(cfg.test_seed0 + i, "val", layouts[(i + len(layouts) // 2) % len(layouts)], cfg.test_city)
        for i in range(cfg.test_worlds)
    ]
    return train + test


def _generate_one(worlds_dir: Path, spec: WorldSpec, cfg: TransferConfig) -> dict:
    """Write one world's AV2 log (a worker process's job); its wall and CPU time."""
    from nuav2.synth import generate_log
    from nuav2.synth.world import clear_world_cache

    t0, c0 = time.perf_counter(), time.process_time()
    generate_log(worlds_dir, spec.seed, synth_config(cfg, spec), spec.split)
    clear_world_cache()
    return {"wall_s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0}


def generate_worlds(cfg: TransferConfig, worlds_dir: Path) -> list[dict]:
    """Write every world's AV2 log that is not there yet (``cfg.workers`` at a time); returns one
    record per world, in ``world_specs`` order."""
    from nuav2.synth.world import world_log_id

    specs = world_specs(cfg)
    records = []
    for spec in specs:
        log_id = world_log_id(spec.seed, synth_config(cfg, spec))
        records.append(
            {
                "seed": spec.seed,
                "split": "train" if spec.split == "train" else "test",
                "layout": spec.layout,
                "city": spec.city,
                "log_id": log_id,
                "generated": not (worlds_dir / spec.split / log_id).is_dir(),
                "wall_s": 0.0,
                "cpu_s": 0.0,
            }
        )
    todo = [(spec, rec) for spec, rec in zip(specs, records) if rec["generated"]]
    if cfg.workers <= 1 or len(todo) <= 1:
        times = [_generate_one(worlds_dir, spec, cfg) for spec, _ in todo]
    else:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        ctx = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(min(cfg.workers, len(todo)), mp_context=ctx) as pool:
            times = list(pool.map(_generate_one, *zip(*[(worlds_dir, spec, cfg) for spec, _ in todo])))
    for (_, rec), t in zip(todo, times):
        rec.update(t)
    return records


def convert_set(cfg: TransferConfig, name: str, worlds_dir: Path, db_dir: Path, progress: bool) -> dict:
    """Convert the worlds of training set ``name`` (truth: train and test worlds) into ``db_dir``."""
    from nuav2.convert import ConvertOptions, convert_av2

    src = worlds_dir if name == "truth" else worlds_dir / "train"
    opts = ConvertOptions(
        mode=name,
        version=cfg.version,
        rig=cfg.target_rig,
        scale=cfg.target_scale,
        recon_preset=cfg.recon_preset,
        show_progress=progress,
        workers=cfg.workers,  # logs in parallel processes (not part of the shards' fingerprint)
    )
    t0, c0 = time.perf_counter(), time.process_time()
    report = convert_av2(src, db_dir, opts)
    if report.failed:
        raise RuntimeError(
            f"{db_dir}: {len(report.failed)} log(s) failed to convert in {name} mode: "
            f"{report.failed[0]['error']} (see {db_dir / 'convert_report.json'})"
        )
    return {
        "dataroot": str(db_dir),
        "mode": name,
        "converted": len(report.converted),
        "resumed": len(report.resumed),
        "samples": report.table_counts.get("sample", 0),
        "wall_s": time.perf_counter() - t0,
        "cpu_s": time.process_time() - c0,
        "load_avg": list(os.getloadavg()),
    }


def split_database(db_dir: Path, version: str, lists_path: Path) -> dict:
    """``nuav2 split DB --version V --lists LISTS``: geo_train / geo_test by world, with leakage report."""
    from nuav2.cli import main

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        rc = main(["split", str(db_dir), "--version", version, "--lists", str(lists_path)])
    if rc != 0:
        raise RuntimeError(f"nuav2 split {db_dir} --lists {lists_path} exited with {rc}")
    return json.loads(buf.getvalue())


def prepare_data(cfg: TransferConfig, out: Path, progress: bool = True) -> dict:
    """Worlds, conversions and splits under ``out``; returns what was done (and reused) with timings."""
    worlds_dir = out / "worlds"
    worlds = generate_worlds(cfg, worlds_dir)
    lists = {
        "train": [w["log_id"] for w in worlds if w["split"] == "train"],
        "test": [w["log_id"] for w in worlds if w["split"] == "test"],
    }
    lists_path = out / "world_lists.json"
    atomic_write_json(lists_path, lists, indent=1)
    conversions, splits = {}, {}
    for name in cfg.sets:
        db = out / "db" / name
        log.info("converting the %s set into %s", name, db)
        conversions[name] = convert_set(cfg, name, worlds_dir, db, progress)
        splits[name] = split_database(db, cfg.version, lists_path)["new"]
    return {"worlds": worlds, "lists": str(lists_path), "conversions": conversions, "splits": splits}


def train_source(cfg: TransferConfig, out: Path, name: str) -> tuple[Path, str]:
    """(dataroot, split) a training set is read from."""
    return out / "db" / name, TRAIN_SPLIT


def test_source(cfg: TransferConfig, out: Path) -> tuple[Path, str]:
    """(dataroot, split) every model is evaluated on: the test worlds' truth in the target rig."""
    return out / "db" / "truth", TEST_SPLIT
