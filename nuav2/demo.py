"""``nuav2 demo``: the whole pipeline on the built-in synthetic scene, end to end.

Per realism preset: synth an AV2 log -> convert it (render mode: reconstruct + render into the
nuScenes rig) -> validate the database and load it in the unmodified devkit -> score every
written image against the synthetic world's exact render of the same camera, over the whole
image and per region (ground, objects, sky), plus the lane-paint offset -> write a side-by-side
PNG (source AV2 views | rendered target views | ground truth).
"""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np

if TYPE_CHECKING:
    from nuav2.convert import ConvertOptions


@dataclass(frozen=True)
class DemoOptions:
    out: Path = Path("nuav2_demo")
    seed: int = 0
    mode: str = "render"
    rig: str = "nuscenes"
    scale: float = 0.25
    recon_preset: str = "fast"
    presets: tuple[str, ...] = ("easy",)  # synthetic realism presets, each into OUT/<preset>/
    version: str = "v1.0-nuav2-demo"
    seconds: float = 2.0
    progress: bool = True


OPTIONS_FILE = "demo_options.json"  # in OUT/<preset>/: the options its log and database were made with
OWNED = ("av2", "nuscenes", "demo_side_by_side.png")  # what the demo writes in OUT/<preset>/ (and replaces)


def _convert_options(options: DemoOptions) -> ConvertOptions:
    """The conversion's options (``nuav2.convert.ConvertOptions``), checked: a bad rig, scale or
    reconstruction preset is one line naming the flag."""
    from nuav2.convert import ConvertOptions

    convert = ConvertOptions(mode=options.mode, version=options.version, rig=options.rig,
                             scale=options.scale, recon_preset=options.recon_preset,
                             show_progress=options.progress)
    convert.check()
    return convert


def check_options(options: DemoOptions) -> None:
    """Refuse bad options before any work: the target rig (loaded as ``convert`` loads it, in every mode),
    scale, reconstruction preset, the presets and the log length."""
    from nuav2.bench.cli_args import check_rig
    from nuav2.synth import SynthConfig

    check_rig(options.rig)
    _convert_options(options)
    if not options.presets:
        raise ValueError("--preset: no preset given")
    for preset in options.presets:
        SynthConfig.for_preset(preset, seconds=options.seconds)


def _options_record(options: DemoOptions, preset: str) -> dict:
    """What OUT/<preset>/'s log and database depend on: the log's preset, seed and length, the database's
    version and mode, and the target rig and reconstruction preset where the mode uses them."""
    converted = options.mode != "native"
    return {"preset": preset, "seed": options.seed, "seconds": options.seconds, "version": options.version,
            "mode": options.mode, "rig": options.rig if converted else None,
            "scale": options.scale if converted else None,
            "recon_preset": options.recon_preset if options.mode == "render" else None}


def prepare_preset_dir(options: DemoOptions, preset: str, out: Path) -> None:
    """Make OUT/<preset>/ hold this run's options: if an earlier run there used other ones (or left no
    record), remove its synthetic log, database and picture, so the new database holds this run's log
    alone (with the same options, the converted log is reused)."""
    from nuav2.atomic import atomic_write_json

    record = _options_record(options, preset)
    try:
        previous = json.loads((out / OPTIONS_FILE).read_text())
    except (OSError, ValueError):
        previous = None
    if previous != record:
        for name in OWNED:
            path = out / name
            if path.is_dir() and not path.is_symlink():
                shutil.rmtree(path)
            elif path.exists() or path.is_symlink():
                path.unlink()
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(out / OPTIONS_FILE, record, indent=1)


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
    """Run every stage per realism preset (into OUT/<preset>/) and return a JSON-able summary with the
    presets side by side (also written to OUT/demo_summary.json)."""
    from nuav2.atomic import atomic_write_json
    from nuav2.bench.cli_args import command_line
    from nuav2.bench.timing import machine

    check_options(options)  # before any work: a bad option leaves nothing behind
    start = machine()
    per_preset = {p: _run_preset(options, p, Path(options.out) / p) for p in options.presets}
    summary = {"command": command_line(), "mode": options.mode, "rig": options.rig, "scale": options.scale,
               "seed": options.seed, "seconds": options.seconds,
               "recon_preset": options.recon_preset if options.mode == "render" else None,
               "machine_at_start": start, "load_1_5_15_at_end": machine()["load_1_5_15"],
               "presets": per_preset}
    atomic_write_json(Path(options.out) / "demo_summary.json", summary, indent=1)
    return summary


def _run_preset(options: DemoOptions, preset: str, out: Path) -> dict:
    """synth -> convert -> validate + devkit -> score per region -> side-by-side PNG, for one preset."""
    from converters.av2 import read_log
    from nuav2.bench.timing import Stopwatch
    from nuav2.convert import convert_av2
    from nuav2.evaluate.against_world import key_camera_images, log_offsets, score_against_world
    from nuav2.maptr.dataset import load_image_rgb
    from nuav2.nuscenes_db.validate import validate_database
    from nuav2.synth import SynthConfig, generate_log, load_world, render_view

    clocks = {k: Stopwatch() for k in ("synth", "convert", "validate", "score")}
    prepare_preset_dir(options, preset, out)
    with clocks["synth"]:
        config = SynthConfig.for_preset(preset, seconds=options.seconds)
        log_dir = generate_log(out / "av2", seed=options.seed, config=config, progress=options.progress)

    dataroot = out / "nuscenes"
    with clocks["convert"]:
        report = convert_av2(log_dir, dataroot, _convert_options(options))
    if report.failed:
        raise RuntimeError(f"demo conversion failed: {report.failed}")

    with clocks["validate"]:
        validation = validate_database(dataroot, options.version, devkit=True)
        if not validation.ok:
            raise RuntimeError(f"demo database failed validation:\n{validation.format_text()}")
        from nuscenes.nuscenes import NuScenes

        nusc = NuScenes(version=options.version, dataroot=str(dataroot), verbose=False)

    scene = read_log(log_dir)
    with clocks["score"]:
        world = load_world(log_dir)
        images = key_camera_images(dataroot, options.version, log_offsets(dataroot, options.version))
        quality = score_against_world(images, world, vector_map=scene.vector_map).summary()

    # Side-by-side of the middle sample.
    mid = nusc.sample[len(nusc.sample) // 2]
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

    return {
        "log_dir": str(log_dir), "dataroot": str(dataroot), "version": options.version,
        "samples": len(nusc.sample), "sample_data": len(nusc.sample_data),
        "annotations": len(nusc.sample_annotation), "validation": "ok",
        "converted_logs": len(report.converted), "reused_logs": len(report.resumed),
        "quality": quality,
        "timings": {k: {"wall_s": round(c.wall_s[0], 2), "cpu_s": round(c.cpu_s[0], 2),
                        "load_1min_after": round(c.load[0], 2)} for k, c in clocks.items()},
        "side_by_side_png": str(png),
    }


def _fmt(v: float | None, spec: str) -> str:
    return "-" if v is None else format(v, spec)


def format_summary(summary: dict) -> str:
    """Human-readable report: one column per preset, then each preset's per-camera figures."""
    presets = summary["presets"]
    names = list(presets)
    q = {p: presets[p]["quality"] for p in names}
    t = {p: presets[p]["timings"] for p in names}

    def row(label: str, cells: list[str]) -> str:
        return f"    {label:<30}" + "".join(f"{c:>18}" for c in cells)

    lines = [f"nuav2 demo: synthetic AV2 log -> {summary['mode']} mode in the {summary['rig']} rig "
             f"(scale {summary['scale']}); {summary['command']}"]
    for p, s in presets.items():
        lines.append(f"  [{p}] {s['dataroot']} ({s['version']}): {s['samples']} samples, {s['sample_data']} "
                     f"sample_data, {s['annotations']} boxes; validate OK, NuScenes() loads")
    lines.append(f"  vs ground truth, mean over target cameras (load at start "
                 f"{summary['machine_at_start']['load_1_5_15']}, at end {summary['load_1_5_15_at_end']})")
    lines.append(row("preset", names))
    for region in ("whole", "ground", "objects", "sky"):
        lines.append(row(f"PSNR dB / SSIM, {region}", [
            f"{_fmt(q[p]['psnr_db'][region], '.2f')} / {_fmt(q[p]['ssim'][region], '.3f')}" for p in names]))
    lines.append(row("lane paint px (truth)", [
        f"{_fmt(q[p]['paint_median_px'], '.2f')} ({_fmt(q[p].get('paint_median_px_truth'), '.2f')})"
        for p in names]))
    for stage in ("synth", "convert", "validate", "score"):
        lines.append(row(f"{stage} s, wall / CPU",
                         [f"{t[p][stage]['wall_s']:.1f} / {t[p][stage]['cpu_s']:.1f}" for p in names]))
    for p, s in presets.items():
        for ch, v in s["quality"]["per_camera"].items():
            w = v["whole"]
            lines.append(f"    [{p}] {ch:<16} PSNR {w['psnr_db']:6.2f} dB  SSIM {w['ssim']:.3f}  "
                         f"({w['images']} images)")
        lines.append(f"    [{p}] picture {s['side_by_side_png']}")
    means = {p: q[p]["psnr_db"]["whole"] for p in names}
    return "\n".join(lines) + "\n" + json.dumps({"psnr_db_mean": means})
