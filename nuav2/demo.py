"""``nuav2 demo``: the whole pipeline on the built-in synthetic scene, end to end.

synth an AV2 log -> convert it (render mode: reconstruct + render into the nuScenes rig) ->
validate the database and load it in the unmodified devkit -> score every rendered image
against the synthetic world's exact render of the same camera -> write a side-by-side PNG
(source AV2 views | rendered target views | ground truth).
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class DemoOptions:
    out: Path = Path("nuav2_demo")
    seed: int = 0
    mode: str = "render"
    rig: str = "nuscenes"
    scale: float = 0.25
    recon_preset: str = "fast"
    version: str = "v1.0-nuav2-demo"
    seconds: float = 2.0
    progress: bool = True


def _tile_row(images: list[np.ndarray], height: int, label: str) -> np.ndarray:
    """Images resized to one height, side by side, with a label strip on the left."""
    tiles = [cv2.resize(im, (max(1, round(im.shape[1] * height / im.shape[0])), height),
                        interpolation=cv2.INTER_AREA) for im in images]
    row = np.concatenate(tiles, axis=1)
    strip = np.full((height, 150, 3), 255, np.uint8)
    cv2.putText(strip, label, (6, height // 2), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    return np.concatenate([strip, row], axis=1)


def side_by_side_png(path: Path, source: list[np.ndarray], rendered: list[np.ndarray],
                     truth: list[np.ndarray], mode: str, height: int = 150) -> None:
    """Three rows: source AV2 views, target-rig images of ``mode``, ground truth (RGB in)."""
    rows = [_tile_row(source, height, "AV2 source"), _tile_row(rendered, height, f"{mode} (target)"),
            _tile_row(truth, height, "ground truth")]
    width = max(r.shape[1] for r in rows)
    rows = [np.pad(r, ((0, 4), (0, width - r.shape[1]), (0, 0)), constant_values=255) for r in rows]
    ok, buf = cv2.imencode(".png", np.concatenate(rows, axis=0)[:, :, ::-1])
    if not ok:
        raise RuntimeError(f"{path}: PNG encoding failed")
    from nuav2.atomic import atomic_write_bytes

    atomic_write_bytes(path, buf.tobytes())


def run_demo(options: DemoOptions) -> dict:
    """Run every stage and return a JSON-able summary (also written to OUT/demo_summary.json)."""
    from converters.av2 import read_log
    from nuav2.convert import ConvertOptions, convert_av2
    from nuav2.evaluate.against_world import key_camera_images, log_offsets, score_against_world
    from nuav2.maptr.dataset import load_image_rgb
    from nuav2.nuscenes_db.validate import validate_database
    from nuav2.synth import SynthConfig, generate_log, load_world, render_view

    out = Path(options.out)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    log_dir = generate_log(out / "av2", seed=options.seed, config=SynthConfig(seconds=options.seconds),
                           progress=options.progress)
    timings["synth_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    dataroot = out / "nuscenes"
    report = convert_av2(log_dir, dataroot, ConvertOptions(
        mode=options.mode, version=options.version, rig=options.rig, scale=options.scale,
        recon_preset=options.recon_preset, show_progress=options.progress))
    timings["convert_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    validation = validate_database(dataroot, options.version, devkit=True)
    if not validation.ok:
        raise RuntimeError(f"demo database failed validation:\n{validation.format_text()}")
    from nuscenes.nuscenes import NuScenes

    nusc = NuScenes(version=options.version, dataroot=str(dataroot), verbose=False)
    timings["validate_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    world = load_world(log_dir)
    images = key_camera_images(dataroot, options.version, log_offsets(dataroot, options.version))
    scores = score_against_world(images, world)
    timings["score_s"] = time.perf_counter() - t0

    # Side-by-side of the middle sample.
    mid = nusc.sample[len(nusc.sample) // 2]
    scene = read_log(log_dir)
    t_mid = mid["timestamp"] * 1000
    source = []
    for ch in scene.rig.camera_channels:
        frames = scene.camera_frames.get(ch, [])
        if frames:
            f = min(frames, key=lambda fr: abs(fr.timestamp_ns - t_mid))
            source.append(load_image_rgb(str(f.path)))
    mid_paths = {Path(nusc.get_sample_data_path(tok)) for tok in mid["data"].values()}
    target = [im for im in images if im.path in mid_paths]
    rendered = [load_image_rgb(str(im.path)) for im in target]
    truth = [render_view(world, im.camera, im.city_T_cam, im.timestamp_ns) for im in target]
    png = out / "demo_side_by_side.png"
    side_by_side_png(png, source, rendered, truth, options.mode)

    per_cam = {ch: s.summary() for ch, s in sorted(scores.items())}
    summary = {
        "log_dir": str(log_dir), "dataroot": str(dataroot), "version": options.version, "mode": options.mode,
        "rig": options.rig, "scale": options.scale, "samples": len(nusc.sample),
        "sample_data": len(nusc.sample_data), "annotations": len(nusc.sample_annotation),
        "validation": "ok", "converted_logs": len(report.converted),
        "psnr_db_mean": float(np.mean([v["psnr_db"] for v in per_cam.values()])),
        "ssim_mean": float(np.mean([v["ssim"] for v in per_cam.values()])),
        "per_camera": per_cam, "timings_s": {k: round(v, 2) for k, v in timings.items()},
        "side_by_side_png": str(png),
    }
    from nuav2.atomic import atomic_write_json

    atomic_write_json(out / "demo_summary.json", summary, indent=1)
    return summary


def format_summary(summary: dict) -> str:
    lines = [
        f"nuav2 demo: synthetic AV2 log -> {summary['mode']} mode in the {summary['rig']} rig "
        f"(scale {summary['scale']})",
        f"  database   {summary['dataroot']} ({summary['version']}): {summary['samples']} samples, "
        f"{summary['sample_data']} sample_data, {summary['annotations']} boxes; "
        "validate OK, NuScenes() loads",
        f"  quality    PSNR {summary['psnr_db_mean']:.2f} dB, SSIM {summary['ssim_mean']:.3f} "
        "vs ground truth (mean over target cameras)",
    ]
    for ch, v in summary["per_camera"].items():
        lines.append(f"             {ch:<16} PSNR {v['psnr_db']:6.2f} dB  SSIM {v['ssim']:.3f}  "
                     f"({v['n']} images)")
    t = summary["timings_s"]
    lines.append(f"  time       synth {t['synth_s']} s, convert {t['convert_s']} s, "
                 f"validate {t['validate_s']} s, score {t['score_s']} s")
    lines.append(f"  picture    {summary['side_by_side_png']}")
    lines.append(f"  summary    {Path(summary['dataroot']).parent / 'demo_summary.json'}")
    return "\n".join(lines) + "\n" + json.dumps({"psnr_db_mean": round(summary["psnr_db_mean"], 3)})
