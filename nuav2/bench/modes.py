"""Benchmark: native vs warp vs render mode on one synthetic log, against the world's ground truth.

Every mode produces (or stands in for) the target rig's camera images at each sample time; the
synthetic world renders the exact image of the same camera at the same pose and time, so each
mode gets a per-camera PSNR / SSIM and a wall time per frame (one frame = all target cameras at
one sample time), all in one process:

- ``native``: what AV2-in-nuScenes-format gives a target camera: the AV2 camera whose optical
  axis is closest, resized to the target intrinsics (no re-rendering), scored only on the
  target pixels that image covers (``coverage`` says how many).
- ``naive``: the same image scored on the whole target image, uncovered pixels filled as the
  warp fills them -- the baseline the warp must beat.
- ``warp``: :class:`nuav2.warp.provider.WarpRenderer`.
- ``render``: Gaussian-splat reconstruction + rendering via ``nuav2.recon`` (time per frame
  with and without the reconstruction amortised over the frames); reported as missing when
  that module is not installed.
Lane-paint alignment (median px offset of map paint vs image paint) is reported for the ground
truth (the measure's floor) and each mode.
"""

from __future__ import annotations

import importlib.util
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from nuav2.bench.paint_alignment import paint_offsets_px, painted_boundary_points
from nuav2.evaluate.image_metrics import psnr, ssim
from nuav2.geometry import F64
from nuav2.progress import progress_bar
from nuav2.rig import CameraSpec, Rig, load_rig
from nuav2.scene import SceneLog
from nuav2.splat.render_target import target_city_T_cams
from nuav2.warp.backward_warp import fill_uncovered
from nuav2.warp.naive import closest_source_camera, resize_to_intrinsics
from nuav2.warp.provider import WarpConfig, WarpRenderer, read_rgb

ImageFn = Callable[[CameraSpec, F64, int], tuple[np.ndarray, np.ndarray | None]]


def target_poses(scene: SceneLog, rig: Rig, t: int) -> list[tuple[CameraSpec, F64]]:
    """Each target camera with its city pose at sweep time ``t`` (frame alignment, paper eq. 1-2)."""
    city_T_cams = target_city_T_cams(scene, rig, t)
    return [(cam, city_T_cams[cam.channel]) for cam in rig.cameras]


def naive_image(scene: SceneLog, cam: CameraSpec, t: int) -> tuple[np.ndarray, np.ndarray]:
    """Closest-axis source camera's image nearest in time, resized to ``cam`` (uint8, covered mask)."""
    src = closest_source_camera(cam, scene.rig)
    frames = scene.camera_frames[src.channel]
    frame = frames[int(np.argmin([abs(int(f.timestamp_ns) - t) for f in frames]))]
    return resize_to_intrinsics(read_rgb(frame.path, src), src, cam)


class _Scores:
    """Per-camera PSNR / SSIM / paint offsets and per-frame times of one mode."""

    def __init__(self) -> None:
        self.psnr: dict[str, list[float]] = {}
        self.ssim: dict[str, list[float]] = {}
        self.coverage: dict[str, list[float]] = {}
        self.paint: list[np.ndarray] = []
        self.frame_s: list[float] = []

    def add(self, cam: CameraSpec, img: np.ndarray, gt: np.ndarray, mask: np.ndarray | None,
            coverage: float | None = None) -> None:
        """Score ``img`` on all pixels (``mask`` None: PSNR and SSIM) or on ``mask`` only (PSNR)."""
        ch = cam.channel
        cov = coverage if coverage is not None else (1.0 if mask is None else float(mask.mean()))
        self.coverage.setdefault(ch, []).append(cov)
        if mask is not None and not np.any(mask):
            return
        self.psnr.setdefault(ch, []).append(psnr(img, gt, data_range=255.0, mask=mask))
        if mask is None:
            self.ssim.setdefault(ch, []).append(ssim(img, gt, data_range=255.0))

    def summary(self) -> dict:
        def per_cam(d: dict[str, list[float]]) -> dict:
            out = {ch: round(float(np.mean(v)), 3) for ch, v in d.items()}
            if d:
                out["mean"] = round(float(np.mean([np.mean(v) for v in d.values()])), 3)
            return out

        paint = np.concatenate(self.paint) if self.paint else np.zeros(0)
        return {"seconds_per_frame": round(float(np.mean(self.frame_s)), 4) if self.frame_s else None,
                "psnr_db": per_cam(self.psnr), "ssim": per_cam(self.ssim), "coverage": per_cam(self.coverage),
                "paint_median_px": round(float(np.median(paint)), 3) if len(paint) else None}


def _recon_available() -> bool:
    return importlib.util.find_spec("nuav2.recon") is not None


def _render_mode(scene: SceneLog, preset: str, progress: bool) -> tuple[Callable, float]:
    """(render fn (channel, cam, city_T_cam, t) -> uint8, reconstruction seconds) from nuav2.recon."""
    from nuav2 import recon

    config = recon.ReconConfig.fast() if preset == "fast" else recon.ReconConfig.default()
    t0 = time.perf_counter()
    splat = recon.reconstruct(scene, config, progress=progress)
    recon_s = time.perf_counter() - t0
    # The plain renderer: render mode's quality gate (extra renders per image) is not timed here.
    return recon.render_provider(splat, quality=False).renderer, recon_s


def bench_modes(seed: int = 0, config=None, rig_name: str = "nuscenes", scale: float = 0.16,
                frame_step: int = 1, with_render: bool = True, recon_preset: str = "default",
                warp_config: WarpConfig | None = None, work_dir: Path | None = None,
                progress: bool = True) -> dict:
    """Run every mode on the synthetic log of ``seed`` (default scene) and return the comparison as a dict."""
    from converters.av2 import read_log
    from nuav2.synth import SynthConfig, generate_log, load_world, render_view

    config = config or SynthConfig()
    with tempfile.TemporaryDirectory(prefix="nuav2_bench_modes_") as tmp:
        root = Path(work_dir) if work_dir is not None else Path(tmp)
        t0 = time.perf_counter()
        log_dir = generate_log(root, seed=seed, config=config)
        synth_s = time.perf_counter() - t0
        phases = {"synthesise_log": synth_s}
        t0 = time.perf_counter()
        scene, world = read_log(log_dir), load_world(log_dir)
        rig = load_rig(rig_name, scale=scale)
        times = [int(t) for t in scene.sweep_timestamps_ns[::max(1, frame_step)]]
        frames = {t: target_poses(scene, rig, t) for t in times}
        gt = {(t, cam.channel): render_view(world, cam, T, t)
              for t, views in frames.items() for cam, T in views}
        phases["read_log_and_ground_truth"] = time.perf_counter() - t0
        paint_pts, paint_dirs = painted_boundary_points(scene.vector_map) if scene.vector_map else (
            np.zeros((0, 3)), np.zeros((0, 3)))
        scores = {m: _Scores() for m in ("native", "naive", "warp", "render")}
        floor = _Scores()

        def paint(s: _Scores, img: np.ndarray, cam: CameraSpec, T: F64) -> None:
            s.paint.append(paint_offsets_px(img, cam, T, paint_pts, paint_dirs))

        for t, views in frames.items():
            for cam, T in views:
                paint(floor, gt[(t, cam.channel)], cam, T)

        # native / naive: one resize per camera.
        t_phase = time.perf_counter()
        for t, views in progress_bar(frames.items(), desc="native", disable=not progress):
            t0 = time.perf_counter()
            out = [(cam, T, *naive_image(scene, cam, t)) for cam, T in views]
            scores["native"].frame_s.append(time.perf_counter() - t0)
            scores["naive"].frame_s.append(scores["native"].frame_s[-1])
            for cam, T, img, cov in out:
                g = gt[(t, cam.channel)]
                scores["native"].add(cam, img, g, cov)
                filled = np.clip(np.rint(fill_uncovered(img.astype(np.float32) / 255, cov) * 255), 0, 255)
                scores["naive"].add(cam, filled.astype(np.uint8), g, None, coverage=float(cov.mean()))
                paint(scores["native"], img, cam, T)

        phases["native_and_scoring"] = time.perf_counter() - t_phase
        # warp
        t_phase = t0 = time.perf_counter()
        warp = WarpRenderer(scene, warp_config)
        cam0, T0 = frames[times[0]][0]
        warp(cam0.channel, cam0, T0, times[0])  # JIT / disk-cache load outside the timing
        warp_setup_s = time.perf_counter() - t0
        warp = WarpRenderer(scene, warp_config)
        for t, views in progress_bar(frames.items(), desc="warp", disable=not progress):
            t0 = time.perf_counter()
            out = [(cam, T, warp(cam.channel, cam, T, t)) for cam, T in views]
            scores["warp"].frame_s.append(time.perf_counter() - t0)
            for cam, T, img in out:
                scores["warp"].add(cam, img, gt[(t, cam.channel)], None,
                                    coverage=warp.coverage[cam.channel][t])
                paint(scores["warp"], img, cam, T)

        phases["warp_and_scoring"] = time.perf_counter() - t_phase
        # render (Gaussian splatting), if the reconstruction module exists
        t_phase = time.perf_counter()
        render_info: dict = {"status": "missing: nuav2.recon is not installed"}
        if with_render and _recon_available():
            render_fn, recon_s = _render_mode(scene, recon_preset, progress)
            for t, views in progress_bar(frames.items(), desc="render", disable=not progress):
                t0 = time.perf_counter()
                out = [(cam, T, np.asarray(render_fn(cam.channel, cam, T, t))) for cam, T in views]
                scores["render"].frame_s.append(time.perf_counter() - t0)
                for cam, T, img in out:
                    scores["render"].add(cam, img, gt[(t, cam.channel)], None)
                    paint(scores["render"], img, cam, T)
            per_frame = float(np.mean(scores["render"].frame_s))
            render_info = {"status": "ok", "preset": recon_preset, "reconstruction_s": round(recon_s, 2),
                           "seconds_per_frame_with_reconstruction": round(per_frame + recon_s / len(times),
                                                                            4)}
            phases["render_and_scoring"] = time.perf_counter() - t_phase
        elif not with_render:
            render_info = {"status": "skipped (--no-render)"}

    modes = {m: s.summary() for m, s in scores.items() if s.frame_s}
    result = {
        "scene": {"seed": seed, "synth_config": config.to_dict(), "log_id": scene.log_id,
                  "synth_seconds": round(synth_s, 2), "source_rig": scene.rig.name,
                  "source_image_size": [scene.rig.cameras[1].width, scene.rig.cameras[1].height]},
        "target": {"rig": rig_name, "scale": scale, "cameras": rig.camera_channels,
                   "image_size": [rig.cameras[0].width, rig.cameras[0].height]},
        "frames": len(times),
        "modes": modes,
        "warp": {"setup_and_first_image_s": round(warp_setup_s, 3)},
        "render": render_info,
        "paint_floor_median_px": floor.summary()["paint_median_px"],
        "phase_seconds": {k: round(v, 2) for k, v in phases.items()},
    }
    if "render" in modes and "warp" in modes:
        w, r = modes["warp"]["seconds_per_frame"], modes["render"]["seconds_per_frame"]
        result["ratios"] = {"render_over_warp_seconds_per_frame": round(r / w, 2),
                            "render_with_reconstruction_over_warp": round(
                                render_info["seconds_per_frame_with_reconstruction"] / w, 2),
                            "warp_minus_render_psnr_db": round(modes["warp"]["psnr_db"]["mean"]
                                                               - modes["render"]["psnr_db"]["mean"], 3)}
    if "warp" in modes:
        result.setdefault("ratios", {})["warp_minus_naive_psnr_db"] = round(
            modes["warp"]["psnr_db"]["mean"] - modes["naive"]["psnr_db"]["mean"], 3)
    return result
