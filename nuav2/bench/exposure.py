"""Benchmark: how close warp mode's exposure solve gets to the camera's true gains, and what it costs.

On a synthetic log with the ``exposure`` factor (``hard`` has it) the log's images are the clean
world times a per-image gain, white balance and vignetting, plus noise. The solve never sees the
world; this benchmark does: for a random sample of source images it divides the image, corrected by
the solved model, by the world's clean render of the same camera and time (``nuav2.synth.render_view``,
which shares no code with the solve). A perfect correction leaves the same ratio in every image
(the log's reference exposure against the world's unit exposure: the gauge, one per colour
channel); what each image's median log ratio differs from the median over the images is the
correction's error for that image. Variants are solved one after another on the same points:

- ``none``: no correction (the spread the cameras really have);
- ``all observations``: every image, every observation, actors' pixels not left out;
- ``boxes left out``: labelled actors' pixels left out, every image, every observation;
- ``shipped``: the defaults: boxes left out, ``observe_hz`` images per camera and second (the others'
  gains interpolated in time), at most ``max_observations_per_point`` per point.
"""

from __future__ import annotations

import dataclasses
import tempfile
import time
from pathlib import Path

import numpy as np

from nuav2.bench.timing import load_1min

VARIANTS = ("none", "all observations", "boxes left out", "shipped")


def _ratio(corrected: np.ndarray, clean: np.ndarray, valid: np.ndarray | None) -> np.ndarray | None:
    """(3,) median log(corrected / clean) over pixels well inside the range in both, or None."""
    a, b = corrected.astype(np.float64), clean.astype(np.float64)
    ok = (a > 15).all(-1) & (a < 240).all(-1) & (b > 15).all(-1) & (b < 240).all(-1)
    if valid is not None:
        ok &= valid
    if ok.sum() < 100:
        return None
    return np.median(np.log(a[ok] / b[ok]), axis=0)


def bench_exposure(preset: str = "hard", seconds: float = 15.0, seed: int = 0, sample: int = 120,
                   work_dir: Path | None = None) -> dict:
    """Solve every variant on one synthetic log; score each on ``sample`` source images (module doc)."""
    import cv2

    from converters.av2 import read_log
    from nuav2.exposure import ExposureModel
    from nuav2.synth import SynthConfig, build_world, generate_log, load_world, render_view
    from nuav2.warp.harmonise import solve_source_exposure, static_points
    from nuav2.warp.provider import WarpRenderer

    with tempfile.TemporaryDirectory(prefix="nuav2_exposure_") as tmp:
        root = Path(work_dir) if work_dir is not None else Path(tmp)
        cfg = SynthConfig.for_preset(preset, seconds=float(seconds))
        if not cfg.exposure:
            raise ValueError(f"--preset {preset}: its images have no exposure effects (use hard)")
        log_dir = root / "train" / build_world(seed, cfg).log_id  # written atomically: present = complete
        if not log_dir.is_dir():  # a --work-dir from an earlier run keeps its log
            log_dir = generate_log(root, seed=seed, config=cfg)
        scene, world = read_log(log_dir), load_world(log_dir)
        warp = WarpRenderer(scene)
        points = static_points(scene, lambda i: warp.cloud.sweep_points(i)[0])
        base = warp.config.harmonise
        runs: dict[str, dict] = {}
        models: dict[str, ExposureModel] = {}
        index: dict = {}
        for name in VARIANTS[1:]:
            boxes = None if name == "all observations" else warp.boxes_at
            solve_cfg = base if name == "shipped" else dataclasses.replace(
                base, max_observations_per_point=0, observe_hz=0.0)
            t0, c0 = time.perf_counter(), time.process_time()
            models[name], index = solve_source_exposure(scene, warp.frames, points, solve_cfg, boxes)
            runs[name] = {"solve_wall_s": round(time.perf_counter() - t0, 2),
                          "solve_cpu_s": round(time.process_time() - c0, 2),
                          "load_1min": round(load_1min(), 2),
                          "observations": models[name].observations,
                          "max_observations_per_point": solve_cfg.max_observations_per_point,
                          "observe_hz": solve_cfg.observe_hz,
                          "actors_left_out": boxes is not None}
        cams = np.array([0] * len(index))  # identity model: one entry per image
        models["none"] = ExposureModel.identity(cams)
        runs["none"] = {"observations": 0}
        keys = list(index)
        rng = np.random.default_rng(seed)
        picked = [keys[i] for i in np.sort(rng.choice(len(keys), min(sample, len(keys)), replace=False))]
        ratios: dict[str, list[np.ndarray]] = {name: [] for name in VARIANTS}
        for ch, j in picked:
            f = warp.frames[ch][j]
            cam = scene.rig.camera(ch)
            city_T_cam = scene.city_T_ego_at(int(f.timestamp_ns)) @ cam.ego_T_cam
            clean = render_view(world, cam, city_T_cam, int(f.timestamp_ns))
            img = np.ascontiguousarray(cv2.imread(f.path)[:, :, ::-1])
            valid = ~cam.ego_mask() if cam.ego_mask_polygons else None
            per = {name: _ratio(models[name].correct(img, index[(ch, j)], cam.K), clean, valid)
                   for name in VARIANTS}
            if all(r is not None for r in per.values()):
                for name, r in per.items():
                    ratios[name].append(r)
        for name in VARIANTS:
            r = np.array(ratios[name])
            gauge = np.median(r, axis=0)
            err = np.abs(r - gauge)
            runs[name].update({"images_scored": len(r), "gauge_log": [round(float(x), 4) for x in gauge],
                               "error_rms_pct": round(100 * float(np.sqrt(np.mean(err**2))), 2),
                               "error_p90_pct": round(100 * float(np.quantile(err.max(1), 0.9)), 2),
                               "error_max_pct": round(100 * float(err.max()), 2)})
        return {"preset": preset, "seconds": float(seconds), "seed": seed, "log_id": scene.log_id,
                "images": len(keys), "static_points": len(points), "variants": runs}


def markdown_table(result: dict, command: str) -> str:
    """The docs' table: per variant, observations, solve time, error against the true gains."""
    head = ("correction", "images read per camera-second", "observations", "solve s wall (CPU)",
            "error rms %", "error p90 %", "error max %", "gauge (log, RGB)")
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for name in VARIANTS:
        v = result["variants"][name]
        t = f"{v['solve_wall_s']:.1f} ({v['solve_cpu_s']:.1f})" if "solve_cpu_s" in v else "–"
        gauge = ", ".join(f"{x:+.3f}" for x in v["gauge_log"])
        hz = v.get("observe_hz")
        rate = "–" if hz is None else ("all" if hz <= 0 else f"{hz:g}")
        lines.append(f"| {name} | {rate} | {v['observations']:,} | {t} | {v['error_rms_pct']:.2f} | "
                     f"{v['error_p90_pct']:.2f} | {v['error_max_pct']:.2f} | {gauge} |")
    loads = [v["load_1min"] for v in result["variants"].values() if "load_1min" in v]
    scored = result["variants"]["shipped"]["images_scored"]
    lines += ["", f"Measured with `{command}`: preset {result['preset']}, {result['seconds']:g} s log, "
                  f"seed {result['seed']}, {result['images']} source images, {result['static_points']:,} "
                  f"static points; error per image and channel = |median log(corrected / clean render) "
                  f"minus its median over the {scored} scored images|; load (1 min) "
                  f"{min(loads):.1f}-{max(loads):.1f}."]
    return "\n".join(lines) + "\n"
