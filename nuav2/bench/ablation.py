"""Benchmark: what each realism factor of the synthetic world costs warp and render mode.

Starting from ``easy``, each factor of ``nuav2.synth.FACTORS`` is switched on alone
(``SynthConfig.for_preset("easy", <factor>=True)``), and the ``medium`` and ``hard`` presets are run
whole; every row is a synthetic log converted by the library (``convert_av2``, warp and render mode
into the target rig) and scored against the world's exact images of the written cameras
(``nuav2.evaluate.against_world``): PSNR and SSIM over the whole image and the ground region, the
lane-paint offset in pixels, and the seconds each step took (wall and CPU). The cost of a factor
is its row minus the easy row of the same seed, averaged over seeds. Rows run one after another
(each mode's conversion of a row back to back); the machine's load is recorded per row.

Also measured: the synthetic world's own speed per preset (frames of the log writer at the log's
scale, world building excluded), and, on request, one picture per preset (source view, target-rig
ground truth, warp, render side by side).
"""

from __future__ import annotations

import shutil
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from nuav2.synth.config import FACTORS

ROW_EASY = "easy"
EXPOSURE_GAINS = "exposure_gains"  # the exposure factor without its sensor noise and extra JPEG compression
ABLATION_FACTORS = (*FACTORS, EXPOSURE_GAINS)
# raw PSNR, PSNR after one per-channel gain per log (the exposure gauge, nuav2.evaluate.against_world), PSNR
# after the log's true mean exposure is taken out (nuav2.synth.camera_effects.reference_gain), SSIM
SCORE_KEYS = ("psnr_db", "psnr_gauge_db", "psnr_ref_db", "ssim")


@dataclass(frozen=True)
class AblationOptions:
    seeds: tuple[int, ...] = (0, 1)
    factors: tuple[str, ...] | None = None  # None: every factor
    presets: tuple[str, ...] = ("medium", "hard")  # whole presets run beside the single factors
    seconds: float = 2.0  # log length
    image_scale: float = 0.125  # the synthetic log's AV2 cameras
    rig: str = "nuscenes"
    scale: float = 0.125  # target rig resolution factor
    recon_preset: str = "fast"
    modes: tuple[str, ...] = ("warp", "render")
    speed_seconds: float = 2.0  # log length of the synth speed measurement (0: skip it)
    pictures: Path | None = None  # write realism_<preset>.png here (from the first seed)
    work_dir: Path | None = None  # keep logs and databases here (default: a temporary directory)
    command: str = ""
    progress: bool = False
    extra: dict = field(default_factory=dict)


def ablation_rows(opts: AblationOptions) -> list[tuple[str, object]]:
    """(row name, SynthConfig): easy, easy + each factor (``exposure_gains``: the exposure factor's drifting
    gains, white balance and vignetting without its sensor noise), then the whole presets."""
    from nuav2.synth import SynthConfig

    base = dict(seconds=opts.seconds, image_scale=opts.image_scale)
    factors = ABLATION_FACTORS if opts.factors is None else opts.factors
    rows = [(ROW_EASY, SynthConfig.for_preset("easy", **base))]
    for f in factors:
        switch = {"exposure": True, "camera_noise": False} if f == EXPOSURE_GAINS else {f: True}
        rows.append((f"+{f}", SynthConfig.for_preset("easy", **base, **switch)))
    rows += [(p, SynthConfig.for_preset(p, **base)) for p in opts.presets]
    return rows


def _timed(fn, *args, **kwargs):
    from nuav2.bench.timing import load_1min

    t0, c0 = time.perf_counter(), time.process_time()
    out = fn(*args, **kwargs)
    return out, {"wall_s": round(time.perf_counter() - t0, 2), "cpu_s": round(time.process_time() - c0, 2),
                 "load_1min": round(load_1min(), 2)}


def _score(dataroot: Path, version: str, world, vector_map, reference_gain) -> tuple[dict, list]:
    from nuav2.evaluate.against_world import key_camera_images, log_offsets, score_against_world

    images = key_camera_images(dataroot, version, log_offsets(dataroot, version))
    s = score_against_world(images, world, vector_map=vector_map, reference_gain=reference_gain).summary()
    return {"psnr_db": {r: s["psnr_db"][r] for r in ("whole", "ground")},
            "psnr_gauge_db": {r: s["psnr_gauge_db"][r] for r in ("whole", "ground")},
            "psnr_ref_db": {r: s["psnr_ref_db"][r] for r in ("whole", "ground")},
            "gauge_log_gain": s["gauge_log_gain"],
            "reference_log_gain": None if reference_gain is None else [
                round(float(x), 4) for x in np.log(reference_gain)],
            "ssim": {r: s["ssim"][r] for r in ("whole", "ground")},
            "paint_median_px": s["paint_median_px"], "paint_median_px_truth": s.get("paint_median_px_truth"),
            "images": s["images"]}, images


def run_row(seed: int, cfg, opts: AblationOptions, root: Path) -> tuple[dict, dict]:
    """One synthetic log, converted in every mode and scored; (row record, {mode: written images})."""
    from converters.av2 import read_log
    from nuav2.convert import ConvertOptions, convert_av2
    from nuav2.synth import generate_log, load_world
    from nuav2.synth.camera_effects import log_reference_gain

    log_dir, synth_t = _timed(generate_log, root / "av2", seed=seed, config=cfg)
    world = load_world(log_dir)
    reference_gain = log_reference_gain(log_dir)
    vector_map = read_log(log_dir).vector_map
    rec = {"seed": seed, "log_id": world.log_id, "layout": world.layout_name, "manoeuvre": world.manoeuvre,
           "frames": cfg.n_sweeps, "synth": synth_t, "modes": {}}
    written = {}
    for mode in opts.modes:
        dataroot = root / mode
        options = ConvertOptions(mode=mode, rig=opts.rig, scale=opts.scale, recon_preset=opts.recon_preset,
                                 show_progress=opts.progress)
        report, conv_t = _timed(convert_av2, log_dir, dataroot, options)
        if report.failed:
            rec["modes"][mode] = {"status": f"failed: {report.failed}"}
            continue
        scores, images = _score(dataroot, options.version, world, vector_map, reference_gain)
        rec["modes"][mode] = {"status": "ok", "convert": conv_t,
                              "seconds_per_frame": round(conv_t["wall_s"] / cfg.n_sweeps, 3), **scores}
        written[mode] = images
    return rec, written


def _delta(row: dict, easy: dict) -> dict:
    out = {}
    for mode, m in row["modes"].items():
        e = easy["modes"].get(mode, {})
        if m.get("status") != "ok" or e.get("status") != "ok":
            continue
        d = {f"{k}_{r}": round(m[k][r] - e[k][r], 3) for k in SCORE_KEYS for r in ("whole", "ground")
             if k in m and k in e and m[k][r] is not None and e[k][r] is not None}
        if m["paint_median_px"] is not None and e["paint_median_px"] is not None:
            d["paint_px"] = round(m["paint_median_px"] - e["paint_median_px"], 3)
        out[mode] = d
    return out


def _mean_rows(records: list[dict]) -> dict:
    """Means over seeds of each mode's metrics, deltas and seconds."""
    out: dict = {"seeds": [r["seed"] for r in records], "layouts": [r["layout"] for r in records],
                 "synth_wall_s": round(float(np.mean([r["synth"]["wall_s"] for r in records])), 2)}
    def mean(values: list) -> float | None:
        values = [v for v in values if v is not None]
        return round(float(np.mean(values)), 3) if values else None

    for mode in sorted({m for r in records for m in r["modes"]}):
        ok = [r["modes"][mode] for r in records if r["modes"].get(mode, {}).get("status") == "ok"]
        if not ok:
            continue
        m = {f"{k}_{reg}": mean([x[k][reg] for x in ok if k in x])
             for k in SCORE_KEYS for reg in ("whole", "ground")}
        m["paint_px"] = mean([x["paint_median_px"] for x in ok])
        m["convert_wall_s"] = mean([x["convert"]["wall_s"] for x in ok])
        m["convert_cpu_s"] = mean([x["convert"]["cpu_s"] for x in ok])
        ok = [r for r in records if r["modes"].get(mode, {}).get("status") == "ok"]
        deltas = [r["delta"][mode] for r in ok if mode in r.get("delta", {})]
        if deltas:
            m["delta"] = {k: round(float(np.mean([d[k] for d in deltas if k in d])), 3) for k in deltas[0]}
        out[mode] = m
    return out


def synth_speed(presets: tuple[str, ...], seconds: float, image_scale: float, seed: int = 0) -> dict:
    """Seconds per frame (one sweep and its 14 ring images) of the log writer per preset, world building
    excluded, presets interleaved over two rounds; CPU time counts every thread."""
    from nuav2.bench.timing import load_1min
    from nuav2.synth import SynthConfig, build_world
    from nuav2.synth.log_writer import write_log

    out: dict = {p: {"wall_s_per_frame": [], "cpu_s_per_frame": [], "load_1min": []} for p in presets}
    for _ in range(2):
        for p in presets:
            cfg = SynthConfig.for_preset(p, seconds=seconds, image_scale=image_scale)
            world = build_world(seed, cfg)
            _ = world.texture.packed  # built once per world, before the clock starts
            with tempfile.TemporaryDirectory(prefix="nuav2_speed_") as tmp:
                t0, c0 = time.perf_counter(), time.process_time()
                write_log(world, Path(tmp))
                n = cfg.n_sweeps
                out[p]["wall_s_per_frame"].append((time.perf_counter() - t0) / n)
                out[p]["cpu_s_per_frame"].append((time.process_time() - c0) / n)
                out[p]["load_1min"].append(load_1min())
    return {p: {"wall_s_per_frame": round(float(np.median(v["wall_s_per_frame"])), 3),
                "cpu_s_per_frame": round(float(np.median(v["cpu_s_per_frame"])), 3),
                "load_1min": [round(min(v["load_1min"]), 2), round(max(v["load_1min"]), 2)],
                "frames": int(round(seconds * 10))} for p, v in out.items()}


def bench_ablation(opts: AblationOptions) -> dict:
    """Run the ablation (and the synth speed per preset); a JSON-able dict."""
    from tqdm import tqdm

    from nuav2.bench.timing import machine

    rows = ablation_rows(opts)
    started = machine()
    records: dict[str, list[dict]] = {name: [] for name, _ in rows}
    with tempfile.TemporaryDirectory(prefix="nuav2_ablation_") as tmp:
        base = Path(opts.work_dir) if opts.work_dir is not None else Path(tmp)
        todo = [(seed, name, cfg) for seed in opts.seeds for name, cfg in rows]
        for seed, name, cfg in tqdm(todo, desc="ablation", disable=not opts.progress):
            root = base / f"seed{seed}" / name.lstrip("+")
            rec, written = run_row(seed, cfg, opts, root)
            if name != ROW_EASY:
                rec["delta"] = _delta(rec, records[ROW_EASY][-1])
            records[name].append(rec)
            if opts.pictures is not None and seed == opts.seeds[0] and name in (ROW_EASY, *opts.presets):
                preset_picture(Path(opts.pictures) / f"realism_{name}.png", root / "av2", written, rec)
            if opts.work_dir is None:
                shutil.rmtree(root, ignore_errors=True)
    result = {
        "benchmark": "realism ablation: each factor alone on top of easy, and the whole presets",
        "command": opts.command,
        "how": (f"{len(opts.seeds)} seeds x {len(rows)} rows, run one after another; each row is a "
                f"{opts.seconds:g} s synthetic log (AV2 rig at scale {opts.image_scale:g}) converted to the "
                f"{opts.rig} rig at scale {opts.scale:g} in {', '.join(opts.modes)} mode (reconstruction "
                f"preset '{opts.recon_preset}'), every key-frame camera image scored against the world's "
                "exact render; delta = row minus the easy row of the same seed; seconds are wall (cpu) "
                "of the whole conversion of the log"),
        "options": {k: (str(v) if isinstance(v, Path) else v) for k, v in asdict(opts).items()
                    if k not in ("command", "extra", "progress")},
        "machine_start": started,
        "rows": {name: _mean_rows(recs) for name, recs in records.items()},
        "per_seed": records,
    }
    if opts.speed_seconds > 0:
        result["synth_speed"] = synth_speed(("easy", "medium", "hard"), opts.speed_seconds, opts.image_scale)
    result["machine_end"] = machine()
    return result


def _label(img: np.ndarray, text: str) -> np.ndarray:
    import cv2

    out = np.ascontiguousarray(img)
    cv2.rectangle(out, (0, 0), (8 * len(text) + 8, 16), (255, 255, 255), -1)
    cv2.putText(out, text, (3, 12), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
    return out


def preset_picture(path: Path, av2_root: Path, written: dict, rec: dict, height: int = 224) -> None:
    """Source view | target-rig ground truth | warp | render, at the log's middle key frame (CAM_FRONT)."""
    import cv2

    from nuav2.atomic import atomic_write_bytes
    from nuav2.maptr.dataset import load_image_rgb
    from nuav2.synth import load_world, render_view

    if not written:
        return
    mode0 = next(iter(written))
    fronts = [im for im in written[mode0] if im.channel == "CAM_FRONT"]
    im = fronts[len(fronts) // 2]
    log_dir = next((av2_root / "train").iterdir())
    world = load_world(log_dir)
    src_dir = log_dir / "sensors" / "cameras" / "ring_front_center"
    stamps = np.array(sorted(int(p.stem) for p in src_dir.glob("*.jpg")))
    src_ts = int(stamps[np.argmin(np.abs(stamps - im.timestamp_ns))])
    tiles = [(load_image_rgb(str(src_dir / f"{src_ts}.jpg")), "AV2 source"),
             (render_view(world, im.camera, im.city_T_cam, im.timestamp_ns), f"{im.channel} truth")]
    for mode, images in written.items():
        match = next(w for w in images if w.channel == "CAM_FRONT" and w.timestamp_ns == im.timestamp_ns)
        tiles.append((load_image_rgb(str(match.path)), mode))
    tiles = [_label(cv2.resize(t, (round(t.shape[1] * height / t.shape[0]), height),
                               interpolation=cv2.INTER_AREA), text) for t, text in tiles]
    gap = np.full((height, 4, 3), 255, np.uint8)
    row = np.concatenate([x for t in tiles for x in (t, gap)][:-1], axis=1)
    ok, buf = cv2.imencode(".png", row[:, :, ::-1])
    path.parent.mkdir(parents=True, exist_ok=True)
    if not ok:
        raise RuntimeError(f"{path}: PNG encoding failed")
    atomic_write_bytes(path, buf.tobytes())


def markdown_table(result: dict) -> str:
    """The docs' table: per row, each mode's scores and their change against easy; how it was measured."""
    modes = result["options"]["modes"]
    head = ["row"] + [f"{m} {c}" for m in modes for c in ("PSNR dB (Δ)", "gauge PSNR (Δ)", "ref. PSNR (Δ)",
                                                           "ground PSNR (Δ)",
                                                           "SSIM (Δ)",
                                                           "ground SSIM (Δ)", "paint px (Δ)",
                                                           "s wall (CPU)")]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]

    def cell(m: dict, key: str, dkey: str) -> str:
        v, d = m.get(key), m.get("delta", {}).get(dkey)
        if v is None:
            return "–"
        return f"{v:.3f}" + (f" ({d:+.3f})" if d is not None else "") if "ssim" in key else (
            f"{v:.2f}" + (f" ({d:+.2f})" if d is not None else ""))

    for name, row in result["rows"].items():
        cells = [name]
        for mode in modes:
            m = row.get(mode, {})
            cells += [cell(m, "psnr_db_whole", "psnr_db_whole"),
                      cell(m, "psnr_gauge_db_whole", "psnr_gauge_db_whole"),
                      cell(m, "psnr_ref_db_whole", "psnr_ref_db_whole"),
                      cell(m, "psnr_db_ground", "psnr_db_ground"),
                      cell(m, "ssim_whole", "ssim_whole"), cell(m, "ssim_ground", "ssim_ground"),
                      cell(m, "paint_px", "paint_px"),
                      f"{m['convert_wall_s']:.0f} ({m['convert_cpu_s']:.0f})" if m else "–"]
        lines.append("| " + " | ".join(cells) + " |")
    load = [result["machine_start"]["load_1_5_15"][0], result["machine_end"]["load_1_5_15"][0]]
    row_loads = [m["convert"]["load_1min"] for recs in result.get("per_seed", {}).values() for r in recs
                 for m in r["modes"].values() if "convert" in m]
    during = f", {min(row_loads):.1f}-{max(row_loads):.1f} during the conversions" if row_loads else ""
    lines += ["", f"Measured with `{result['command']}`: {result['how']}. Gauge PSNR: after one gain per "
                  "colour channel for the whole log, fitted to the truth (the reference exposure's offset "
                  "from the world's unit exposure, which no image reveals). Ref. PSNR: after the log's "
                  "true mean exposure (the geometric mean of the cameras' recorded gains and white balance, "
                  "nothing fitted) is taken out of the images; the raw PSNR where the cameras had no "
                  "exposure effects. Load (1 min) "
                  f"{load[0]:.1f} at the start, {load[1]:.1f} at the end{during}, on "
                  f"{result['machine_start']['cpu_count']} cores."]
    table = "\n".join(lines) + "\n"
    return table + ("\n" + speed_markdown(result) if "synth_speed" in result else "")


def speed_markdown(result: dict) -> str:
    """The synth speed table (seconds per frame per preset, wall and CPU, the load while measured)."""
    lines = ["| preset | synth s / frame, wall | CPU | load (1 min) |", "|---|---|---|---|"]
    lines += [f"| {p} | {v['wall_s_per_frame']:.2f} | {v['cpu_s_per_frame']:.2f} | "
              f"{v['load_1min'][0]:.1f}-{v['load_1min'][1]:.1f} |" for p, v in result["synth_speed"].items()]
    return "\n".join(lines) + "\n"
