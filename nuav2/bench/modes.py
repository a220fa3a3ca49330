"""Benchmark: warp vs render mode vs the rotation-homography baseline, on synthetic logs, against truth.

Every candidate produces the target rig's camera images at each frame (one frame = all target
cameras at one sweep time, what the writer renders per sample); the synthetic world renders the
exact image of the same camera at the same pose and time, so each candidate gets PSNR / SSIM per
region (whole, ground, objects, sky) and the lane-paint offset, all in one process.

Timing is interleaved: frame by frame, each candidate renders its frame in turn (the order rotates
per frame), so load from other jobs falls on all of them alike; wall and CPU seconds are taken per
frame with the load. One-off costs are timed on their own: the warp's set-up (LiDAR aggregation,
box tracks, the source-exposure solve) and render mode's reconstruction, and the amortised cost per
frame adds them spread over the log's frames. Candidates:

- ``rotation``: the closest-axis source camera's nearest image turned into the target view by the
  rotation homography ``K_t R K_s^-1`` (no depth), uncovered pixels filled as the warp fills them;
- ``rotation_mosaic``: the same with every ring camera (each pixel from the camera closest to its ray);
- ``warp``: :class:`nuav2.warp.provider.WarpRenderer`;
- ``render``: reconstruction + rendering via ``nuav2.recon`` (quality gate off);
- ``mean_colour`` (scored, not timed): a flat image of the truth's own mean colour, the floor any
  candidate must clear.
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np

from nuav2.bench.timing import Stopwatch, machine
from nuav2.evaluate.against_world import RegionScores, truth_view
from nuav2.geometry import F64
from nuav2.progress import progress_bar
from nuav2.rig import CameraSpec, Rig, load_rig
from nuav2.scene import SceneLog
from nuav2.splat.render_target import target_city_T_cams
from nuav2.warp.backward_warp import fill_uncovered
from nuav2.warp.provider import WarpConfig, WarpRenderer, read_rgb
from nuav2.warp.rotation_baseline import RotationSource, closest_source_camera, rotate_into_target

TIMED = ("rotation", "rotation_mosaic", "warp", "render")
FLOOR = "mean_colour"
# A frame producer: (target camera, its city pose, time) for each camera of the frame -> uint8 images.
FrameFn = Callable[[list[tuple[CameraSpec, F64]], int], list[np.ndarray]]


def target_poses(scene: SceneLog, rig: Rig, t: int) -> list[tuple[CameraSpec, F64]]:
    """Each target camera with its city pose at sweep time ``t`` (frame alignment, paper eq. 1-2)."""
    city_T_cams = target_city_T_cams(scene, rig, t)
    return [(cam, city_T_cams[cam.channel]) for cam in rig.cameras]


def rotation_frame_fn(scene: SceneLog, mosaic: bool) -> FrameFn:
    """The rotation-homography baseline: per target camera the nearest-in-time image of the closest-axis
    source camera (or of every ring camera with ``mosaic``), turned into the target view, holes filled."""
    cams = [c for c in scene.rig.cameras if scene.camera_frames.get(c.channel)]
    ring = replace(scene.rig, cameras=tuple(cams))  # cameras with images (no stereo pair when absent)
    frame_ns = {c.channel: np.array([f.timestamp_ns for f in scene.camera_frames[c.channel]]) for c in cams}

    def source(cam: CameraSpec, t: int) -> RotationSource:
        frames = scene.camera_frames[cam.channel]
        frame = frames[int(np.argmin(np.abs(frame_ns[cam.channel] - t)))]
        city_T_cam = scene.city_T_ego_at(int(frame.timestamp_ns)) @ cam.ego_T_cam
        return RotationSource(read_rgb(frame.path, cam), cam, city_T_cam)

    def frame_fn(views: list[tuple[CameraSpec, F64]], t: int) -> list[np.ndarray]:
        loaded: dict[str, RotationSource] = {}  # each source image read once per frame

        def get(c: CameraSpec) -> RotationSource:
            if c.channel not in loaded:
                loaded[c.channel] = source(c, t)
            return loaded[c.channel]

        out = []
        for cam, T in views:
            srcs = [get(c) for c in cams] if mosaic else [get(closest_source_camera(cam, ring))]
            img, covered = rotate_into_target(srcs, cam, T)
            filled = fill_uncovered(img.astype(np.float32) / 255.0, covered)
            out.append(np.clip(np.rint(filled * 255.0), 0, 255).astype(np.uint8))
        return out

    return frame_fn


def mean_colour_image(truth: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """A flat uint8 image of the truth's mean colour over its non-ego pixels (the quality floor)."""
    from nuav2.evaluate.against_world import world_region_masks

    keep = world_region_masks(labels)["whole"]
    colour = truth[keep].mean(axis=0) if np.any(keep) else truth.reshape(-1, 3).mean(axis=0)
    return np.broadcast_to(np.rint(colour).astype(np.uint8), truth.shape).copy()


def _render_setup(scene: SceneLog, config, progress: bool) -> tuple[FrameFn, Stopwatch]:
    """(render frame producer, stopwatch of the reconstruction with ``config``, a ReconConfig)."""
    from nuav2 import recon

    sw = Stopwatch()
    with sw:
        splat = recon.reconstruct(scene, config, progress=progress)
    # The plain renderer: render mode's quality gate (extra renders per image) is not timed here.
    renderer = recon.render_provider(splat, quality=False).renderer

    def frame_fn(views: list[tuple[CameraSpec, F64]], t: int) -> list[np.ndarray]:
        return [np.asarray(renderer(cam.channel, cam, T, t)) for cam, T in views]

    return frame_fn, sw


def _warp_setup(scene: SceneLog, config: WarpConfig | None) -> tuple[FrameFn, Stopwatch]:
    sw = Stopwatch()
    with sw:
        warp = WarpRenderer(scene, config)
        warp.exposure()  # the source-exposure solve, lazy otherwise: set-up, not the first frame

    def frame_fn(views: list[tuple[CameraSpec, F64]], t: int) -> list[np.ndarray]:
        return [warp(cam.channel, cam, T, t) for cam, T in views]

    return frame_fn, sw


def _mode_summary(scores: RegionScores, per_frame: Stopwatch | None, first: Stopwatch | None,
                  setup: Stopwatch | None, n_frames: int) -> dict:
    out: dict = {"quality": scores.summary()}
    if per_frame is not None:
        out["per_frame"] = per_frame.summary()
    if first is not None:  # JIT compilation / lazy set-up; not part of the per-frame or amortised figures
        out["first_frame"] = {"wall_s": round(first.wall_s[0], 3), "cpu_s": round(first.cpu_s[0], 3)}
    if setup is not None:
        out["setup"] = {"wall_s": round(setup.wall_s[0], 2), "cpu_s": round(setup.cpu_s[0], 2),
                        "load_1min_after": round(setup.load[0], 2)}
        pf = out["per_frame"]
        out["amortised_per_frame"] = {"wall_s": round(pf["wall_s_mean"] + setup.wall_s[0] / n_frames, 4),
                                      "cpu_s": round(pf["cpu_s_mean"] + setup.cpu_s[0] / n_frames, 4)}
    return out


def bench_one_log(preset: str, seconds: float, *, seed: int = 0, image_scale: float | None = None,
                  rig_name: str = "nuscenes", scale: float = 0.16, frame_step: int = 1,
                  with_render: bool = True, recon_preset: str = "fast", recon_config=None,
                  synth_overrides: dict | None = None, warp_config: WarpConfig | None = None,
                  work_dir: Path | None = None, progress: bool = True) -> dict:
    """Every candidate on one synthetic log (``preset``, ``seconds`` long), interleaved frame by frame.

    ``recon_config`` (a ReconConfig) replaces ``recon_preset``; ``synth_overrides`` are further
    SynthConfig fields (tests use them for tiny logs)."""
    from converters.av2 import read_log
    from nuav2.synth import SynthConfig, generate_log, load_world

    overrides = {**(synth_overrides or {}), "seconds": float(seconds)}
    if image_scale:
        overrides["image_scale"] = image_scale
    config = SynthConfig.for_preset(preset, **overrides)
    with tempfile.TemporaryDirectory(prefix="nuav2_bench_modes_") as tmp:
        root = Path(work_dir) / f"{preset}_{seconds:g}s_seed{seed}" if work_dir is not None else Path(tmp)
        synth_sw = Stopwatch()
        with synth_sw:
            log_dir = generate_log(root, seed=seed, config=config, progress=progress)
        scene, world = read_log(log_dir), load_world(log_dir)
        rig = load_rig(rig_name, scale=scale)
        times = [int(t) for t in scene.sweep_timestamps_ns[::max(1, frame_step)]]
        producers: dict[str, FrameFn] = {"rotation": rotation_frame_fn(scene, mosaic=False),
                                         "rotation_mosaic": rotation_frame_fn(scene, mosaic=True)}
        setups: dict[str, Stopwatch] = {}
        producers["warp"], setups["warp"] = _warp_setup(scene, warp_config)
        render_status = "skipped (--no-render)"
        if with_render:
            from nuav2.recon import ReconConfig

            producers["render"], setups["render"] = _render_setup(
                scene, recon_config or ReconConfig.preset(recon_preset), progress)
            render_status = "ok"
        first = target_poses(scene, rig, times[0])[:1]
        firsts = {m: Stopwatch() for m in producers}
        for m, fn in producers.items():  # JIT compilation / first-call overheads, timed apart
            with firsts[m]:
                fn(first, times[0])
        timers = {m: Stopwatch() for m in producers}
        scores = {m: RegionScores.for_map(scene.vector_map) for m in (*producers, FLOOR)}
        bar = progress_bar(times, desc=f"{preset} {seconds:g}s frames", disable=not progress)
        for i, t in enumerate(bar):
            views = target_poses(scene, rig, t)
            order = list(producers)[i % len(producers):] + list(producers)[:i % len(producers)]
            images: dict[str, list[np.ndarray]] = {}
            for m in order:
                with timers[m]:
                    images[m] = producers[m](views, t)
            for k, (cam, T) in enumerate(views):
                truth, labels = truth_view(world, cam, T, t)
                for m, imgs in images.items():
                    scores[m].add(cam, T, imgs[k], truth, labels, with_paint_floor=(m == "warp"))
                scores[FLOOR].add(cam, T, mean_colour_image(truth, labels), truth, labels)
    n = len(times)
    modes = {m: _mode_summary(scores[m], timers.get(m), firsts.get(m), setups.get(m), n)
             for m in (*producers, FLOOR)}
    paint_floor = modes["warp"]["quality"].get("paint_median_px_truth")
    return {"preset": preset, "seconds": float(seconds), "seed": seed, "log_id": scene.log_id,
            "synth_config": config.to_dict(), "synth_s": round(synth_sw.wall_s[0], 2),
            "source_image_size": max([c.width, c.height] for c in scene.rig.cameras),  # the landscape size
            "target": {"rig": rig_name, "scale": scale, "cameras": rig.camera_channels,
                       "image_size": [rig.cameras[0].width, rig.cameras[0].height]},
            "frames": n, "images_per_frame": len(rig.cameras),
            "recon_preset": (recon_preset if recon_config is None else "custom") if with_render else None,
            "render_status": render_status, "paint_floor_median_px": paint_floor,
            "modes": modes, "ratios": _ratios(modes)}


def _ratios(modes: dict) -> dict:
    """Render over warp per frame (wall and CPU) and amortised; dB gaps between candidates."""
    out: dict = {}
    w, r = modes.get("warp"), modes.get("render")
    if w and r:
        for clock in ("wall", "cpu"):
            out[f"render_over_warp_per_frame_{clock}"] = round(
                r["per_frame"][f"{clock}_s_mean"] / w["per_frame"][f"{clock}_s_mean"], 2)
            out[f"render_over_warp_amortised_{clock}"] = round(
                r["amortised_per_frame"][f"{clock}_s"] / w["amortised_per_frame"][f"{clock}_s"], 2)
    whole = {m: v["quality"]["psnr_db"]["whole"] for m, v in modes.items()}
    pairs = (("warp", "rotation"), ("warp", "mean_colour"), ("warp", "render"), ("rotation", "mean_colour"))
    for a, b in pairs:
        if whole.get(a) is not None and whole.get(b) is not None:
            out[f"{a}_minus_{b}_psnr_db"] = round(whole[a] - whole[b], 3)
    return out


def bench_modes(presets: tuple[str, ...] = ("easy",), seconds: tuple[float, ...] = (2.0,),
                seeds: tuple[int, ...] = (0,), *, command: str | None = None, **kw) -> dict:
    """One :func:`bench_one_log` per (log length, seed, preset), in this order, plus a side-by-side table."""
    start = machine()
    runs = [bench_one_log(p, s, seed=seed, **kw) for s in seconds for seed in seeds for p in presets]
    return {"command": command, "interleaved": True, "machine_at_start": start, "seeds": list(seeds),
            "load_1_5_15_at_end": machine()["load_1_5_15"], "runs": runs, "table": side_by_side(runs)}


def side_by_side(runs: list[dict]) -> list[dict]:
    """One flat row per (run, candidate): the figures the docs tables print."""
    rows = []
    for run in runs:
        for m, v in run["modes"].items():
            q = v["quality"]
            row = {"preset": run["preset"], "seconds": run["seconds"], "seed": run["seed"],
                   "frames": run["frames"], "mode": m,
                   **{f"psnr_{r}": q["psnr_db"][r] for r in q["psnr_db"]},
                   **{f"ssim_{r}": q["ssim"][r] for r in q["ssim"]},
                   "paint_px": q["paint_median_px"]}
            if "per_frame" in v:
                pf = v["per_frame"]
                row |= {"frame_wall_s": pf["wall_s_mean"], "frame_cpu_s": pf["cpu_s_mean"],
                        "frame_load": pf["load_1min"]}
            if "setup" in v:
                row |= {"setup_wall_s": v["setup"]["wall_s"], "setup_cpu_s": v["setup"]["cpu_s"],
                        "amortised_wall_s": v["amortised_per_frame"]["wall_s"],
                        "amortised_cpu_s": v["amortised_per_frame"]["cpu_s"]}
            rows.append(row)
    return rows
