"""Benchmark and evaluation of reconstructions on synthetic logs: speed against error.

A synthetic log's world renders exact ground truth for any camera, so a reconstruction is
scored where it matters for nuAV2: rendered in the *target* rig (nuScenes by default, at the
same pose the writer would use) against the world's own render of that camera. Also reported:
PSNR on held-out *source* images (every k-th image of each camera, never trained on) and lane
paint alignment (map paint projected into the rendered target images vs the paint found there,
with the same measure on ground truth as the floor).

``bench_recon`` runs several budgets (iterations x Gaussian budget x training resolution) on
one log in one process; ratios are against the cheapest budget of the same run.
"""

from __future__ import annotations

import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from nuav2.rig import load_rig
from nuav2.scene import SceneLog
from nuav2.splat.render_target import target_city_T_cams, to_uint8
from nuav2.splat.scene_model import SplatScene

DEFAULT_TARGET_RIG = "nuscenes"
DEFAULT_TARGET_SCALE = 0.125  # nuScenes 1600x900 -> 200x112, the resolution of the default synthetic log


def eval_times(scene: SceneLog, n: int) -> np.ndarray:
    """``n`` sweep timestamps spread over the log (the writer's sample times)."""
    ts = scene.sweep_timestamps_ns
    idx = np.unique(np.linspace(0, len(ts) - 1, max(1, min(n, len(ts)))).round().astype(int))
    return ts[idx]


def target_rig_scores(splat: SplatScene, scene: SceneLog, world, *, rig: str = DEFAULT_TARGET_RIG,
                      scale: float = DEFAULT_TARGET_SCALE, n_times: int = 6, paint: bool = True) -> dict:
    """PSNR/SSIM per target camera vs the world's ground truth, and lane-paint alignment."""
    import torch

    from nuav2.bench.paint_alignment import paint_offsets_px, painted_boundary_points
    from nuav2.evaluate.image_metrics import psnr, ssim
    from nuav2.synth import render_view

    target = load_rig(rig, scale=scale)
    per_cam: dict[str, dict[str, list[float]]] = {c.channel: {"psnr": [], "ssim": []} for c in target.cameras}
    paint_pts = painted_boundary_points(scene.vector_map) if (paint and scene.vector_map) else None
    off_render, off_truth = [], []
    t0 = time.perf_counter()
    n_images = 0
    for t in eval_times(scene, n_times):
        poses = target_city_T_cams(scene, target, int(t))
        for cam in target.cameras:
            truth = render_view(world, cam, poses[cam.channel], int(t))
            with torch.no_grad():
                img = to_uint8(splat.render(cam, poses[cam.channel], int(t)).rgb)
            n_images += 1
            per_cam[cam.channel]["psnr"].append(psnr(img / 255.0, truth / 255.0))
            per_cam[cam.channel]["ssim"].append(ssim(img / 255.0, truth / 255.0))
            if paint_pts is not None and len(paint_pts[0]):
                off_render.append(paint_offsets_px(img, cam, poses[cam.channel], *paint_pts))
                off_truth.append(paint_offsets_px(truth, cam, poses[cam.channel], *paint_pts))
    seconds = time.perf_counter() - t0
    cams = {ch: {"psnr_db": float(np.mean(v["psnr"])), "ssim": float(np.mean(v["ssim"]))}
            for ch, v in per_cam.items()}
    out = {"rig": rig, "scale": scale, "images": n_images, "render_and_truth_s": seconds,
           "psnr_db": float(np.mean([c["psnr_db"] for c in cams.values()])),
           "ssim": float(np.mean([c["ssim"] for c in cams.values()])), "per_camera": cams}
    if off_render:
        r, g = np.concatenate(off_render), np.concatenate(off_truth)
        out["paint"] = {"median_px_render": float(np.median(r)) if len(r) else None,
                        "median_px_truth": float(np.median(g)) if len(g) else None,
                        "points_render": int(len(r)), "points_truth": int(len(g))}
    return out


def render_whole_log_s(splat: SplatScene, scene: SceneLog, *, rig: str = DEFAULT_TARGET_RIG,
                       scale: float = DEFAULT_TARGET_SCALE) -> float:
    """Seconds to render every target camera at every sweep time (what render mode writes)."""
    import torch

    target = load_rig(rig, scale=scale)
    t0 = time.perf_counter()
    for t in scene.sweep_timestamps_ns:
        poses = target_city_T_cams(scene, target, int(t))
        for cam in target.cameras:
            with torch.no_grad():
                to_uint8(splat.render(cam, poses[cam.channel], int(t)).rgb)
    return time.perf_counter() - t0


def heldout_psnr(splat: SplatScene, scene: SceneLog) -> dict | None:
    """Mean PSNR/SSIM on the held-out source images recorded in ``splat.info`` (ego body masked)."""
    import torch

    from nuav2.evaluate.image_metrics import psnr
    from nuav2.recon import views_from_records
    from nuav2.splat.init import load_image

    records = splat.info.get("heldout_views") or []
    if not records:
        return None
    masks = {c.channel: c for c in scene.rig.cameras}
    vals = []
    for view in views_from_records(records):
        img = load_image(view.path, view.cam.width, view.cam.height)
        with torch.no_grad():
            out = splat.render(view.cam, view.city_T_cam, view.timestamp_ns).rgb.clamp(0, 1).numpy()
        spec = masks.get(view.channel)
        valid = None
        if spec is not None and spec.ego_mask_polygons:
            valid = ~spec.scaled(view.cam.width / spec.width).ego_mask()
            if valid.shape != out.shape[:2]:
                valid = None
        vals.append(psnr(out, img, mask=valid))
    return {"images": len(vals), "psnr_db": float(np.mean(vals))}


def default_budgets() -> list[dict]:
    """Budgets from 'seeding only' up to the default config (name, iterations, Gaussian budget,
    training image width)."""
    return [
        {"name": "init-only", "iterations": 0, "gaussians": 90_000, "train_width_px": 256},
        {"name": "fast", "iterations": 600, "gaussians": 90_000, "train_width_px": 256},
        {"name": "half-res", "iterations": 1200, "gaussians": 90_000, "train_width_px": 128},
        {"name": "medium", "iterations": 1200, "gaussians": 90_000, "train_width_px": 256},
        {"name": "default", "iterations": 2000, "gaussians": 100_000, "train_width_px": 256},
        {"name": "large", "iterations": 3000, "gaussians": 200_000, "train_width_px": 256},
    ]


def config_for(budget: dict, holdout_every: int):
    from nuav2.recon import ReconConfig

    base = ReconConfig.fast() if budget["name"] in ("init-only", "fast") else ReconConfig.default()
    # (fast and init-only train on every other image, like the fast preset; the rest on all)
    n = int(budget["iterations"])
    dens = replace(base.train.densify, budget=int(budget["gaussians"]), stop=int(0.8 * n))
    init = replace(base.init, max_background=min(base.init.max_background, int(budget["gaussians"])))
    return replace(base, train_width_px=int(budget["train_width_px"]), holdout_every=holdout_every, init=init,
                   train=replace(base.train, iterations=n, densify=dens))


def bench_recon(log_dir: str | Path | None = None, *, seed: int = 0, budgets: list[dict] | None = None,
                holdout_every: int = 5, n_times: int = 6, progress: bool = False) -> dict:
    """Speed-against-error table on a synthetic log (generated with defaults if ``log_dir`` is None)."""
    from converters.av2 import read_log
    from nuav2.recon import reconstruct
    from nuav2.synth import generate_log, load_world

    with tempfile.TemporaryDirectory(prefix="nuav2-bench-recon-") as tmp:
        if log_dir is None:
            t0 = time.perf_counter()
            log_dir = generate_log(Path(tmp), seed=seed)
            gen_s = time.perf_counter() - t0
        else:
            gen_s = 0.0
        scene = read_log(Path(log_dir))
        world = load_world(Path(log_dir))
        rows = []
        for b in budgets or default_budgets():
            cfg = config_for(b, holdout_every)
            t0 = time.perf_counter()
            splat = reconstruct(scene, cfg, progress=progress)
            wall = time.perf_counter() - t0
            row = {**b, "recon_s": wall, "final_gaussians": splat.num_gaussians(),
                   "init_s": splat.info.get("init_seconds")}
            row["render_log_s"] = render_whole_log_s(splat, scene)
            row["recon_plus_render_s"] = wall + row["render_log_s"]
            t1 = time.perf_counter()
            row["target"] = target_rig_scores(splat, scene, world, n_times=n_times)
            row["target_render_s"] = time.perf_counter() - t1
            row["heldout"] = heldout_psnr(splat, scene)
            rows.append(row)
        base = rows[0]
        for r in rows:
            r["time_ratio"] = r["recon_s"] / max(base["recon_s"], 1e-9)
            r["target_psnr_gain_db"] = r["target"]["psnr_db"] - base["target"]["psnr_db"]
        return {"log_id": scene.log_id, "seed": seed, "generate_s": gen_s,
                "source_images": int(sum(len(v) for v in scene.camera_frames.values())),
                "baseline": base["name"], "rows": rows}


def plot_bench(result: dict, path: str | Path) -> None:
    """PNG of target-rig and held-out PSNR against reconstruction wall time, one point per budget."""
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from nuav2.atomic import atomic_write_bytes

    rows = result["rows"]
    t = [r["recon_s"] for r in rows]
    fig, ax = plt.subplots(figsize=(6.4, 4.0), dpi=110)
    ax.plot(t, [r["target"]["psnr_db"] for r in rows], "o-", label="target rig (nuScenes) vs truth")
    held = [(r["recon_s"], r["heldout"]["psnr_db"]) for r in rows if r.get("heldout")]
    if held:
        ax.plot(*zip(*held), "s--", label="held-out source views")
    for r in rows:
        ax.annotate(r["name"], (r["recon_s"], r["target"]["psnr_db"]), textcoords="offset points",
                    xytext=(4, -12), fontsize=8)
    ax.set_xlabel("reconstruction wall time (s, 2 threads)")
    ax.set_ylabel("PSNR (dB)")
    ax.set_title(f"nuav2 bench recon, synthetic seed {result['seed']}")
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    plt.close(fig)
    atomic_write_bytes(Path(path), buf.getvalue())
