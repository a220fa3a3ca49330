"""Benchmark and evaluation of reconstructions on synthetic logs: speed against error.

A synthetic log's world renders exact ground truth for any camera, so a reconstruction is
scored where it matters for nuAV2: rendered in the *target* rig (nuScenes by default, at the
same pose the writer would use) against the world's own render of that camera. Also reported:
PSNR on held-out *source* images (every k-th image of each camera, never trained on) and lane
paint alignment (map paint projected into the rendered target images vs the paint found there,
with the same measure on ground truth as the floor).

``bench_recon`` runs several budgets (iterations x Gaussian budget x training resolution) on
one log per realism preset and seed, in one process (one after another, not interleaved: a
reconstruction is one long job); ratios are against the cheapest budget of the same log. Target
quality is reported per region (whole, ground, objects, sky), and over seeds as mean and spread,
the seed the reconstruction presets were tuned on (``TUNED``) apart.
"""

from __future__ import annotations

import itertools
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from nuav2.bench.timing import Stopwatch, machine
from nuav2.rig import load_rig
from nuav2.scene import SceneLog
from nuav2.splat.render_target import target_city_T_cams, to_uint8
from nuav2.splat.scene_model import SplatScene

DEFAULT_TARGET_RIG = "nuscenes"
DEFAULT_TARGET_SCALE = 0.125  # nuScenes 1600x900 -> 200x112, the resolution of the default synthetic log
# (synthetic preset, seed) the reconstruction presets were tuned on; every other seed is unseen.
TUNED = frozenset({("easy", 0)})
# Scene variants (``--scene``): SynthConfig overrides on top of the preset. ``empty``: a straight road
# (the arterial layout, the ego keeping its lane) with no traffic at all; ``busy``: the four-way junction
# with twice the default traffic. The scene budget should give the first far fewer Gaussians.
SCENES: dict[str, dict] = {
    "empty": {"layout": "arterial", "lane_change": False, "n_parked": 0, "n_moving": 0, "n_pedestrians": 0,
              "n_cyclists": 0},
    "busy": {"layout": "four_way", "n_parked": 12, "n_moving": 6, "n_pedestrians": 3, "n_cyclists": 2},
}


def eval_times(scene: SceneLog, n: int) -> np.ndarray:
    """``n`` sweep timestamps spread over the log (the writer's sample times)."""
    ts = scene.sweep_timestamps_ns
    idx = np.unique(np.linspace(0, len(ts) - 1, max(1, min(n, len(ts)))).round().astype(int))
    return ts[idx]


def target_rig_scores(splat: SplatScene, scene: SceneLog, world, *, rig: str = DEFAULT_TARGET_RIG,
                      scale: float = DEFAULT_TARGET_SCALE, n_times: int = 6, paint: bool = True) -> dict:
    """PSNR/SSIM per target camera vs the world's ground truth, over the whole image and per region
    (``regions``), and lane-paint alignment (with ground truth's own offset as the floor)."""
    import torch

    from nuav2.evaluate.against_world import RegionScores, truth_view

    target = load_rig(rig, scale=scale)
    scores = RegionScores.for_map(scene.vector_map if paint else None)
    t0 = time.perf_counter()
    for t in eval_times(scene, n_times):
        poses = target_city_T_cams(scene, target, int(t))
        for cam in target.cameras:
            truth, labels = truth_view(world, cam, poses[cam.channel], int(t))
            with torch.no_grad():
                img = to_uint8(splat.render(cam, poses[cam.channel], int(t)).rgb)
            scores.add(cam, poses[cam.channel], img, truth, labels, with_paint_floor=True)
    seconds = time.perf_counter() - t0
    q = scores.summary()
    cams = {ch: {"psnr_db": v["whole"]["psnr_db"], "ssim": v["whole"]["ssim"]}
            for ch, v in q["per_camera"].items()}
    out = {"rig": rig, "scale": scale, "images": q["images"], "render_and_truth_s": seconds,
           "psnr_db": q["psnr_db"]["whole"], "ssim": q["ssim"]["whole"], "per_camera": cams,
           "regions": {"psnr_db": q["psnr_db"], "ssim": q["ssim"]}}
    if scores.paint_points is not None:
        out["paint"] = {"median_px_render": q["paint_median_px"], "points_render": q["paint_points"],
                        "median_px_truth": q["paint_median_px_truth"],
                        "points_truth": q["paint_points_truth"]}
    return out


def render_whole_log_s(splat: SplatScene, scene: SceneLog, *, rig: str = DEFAULT_TARGET_RIG,
                       scale: float = DEFAULT_TARGET_SCALE) -> Stopwatch:
    """Wall and CPU seconds to render every target camera at every sweep time (what render mode writes)."""
    import torch

    target = load_rig(rig, scale=scale)
    sw = Stopwatch()
    with sw:
        for t in scene.sweep_timestamps_ns:
            poses = target_city_T_cams(scene, target, int(t))
            for cam in target.cameras:
                with torch.no_grad():
                    to_uint8(splat.render(cam, poses[cam.channel], int(t)).rgb)
    return sw


def heldout_psnr(splat: SplatScene, scene: SceneLog, views: str = "heldout_views") -> dict | None:
    """Mean PSNR on the held-out source images recorded in ``splat.info[views]`` (ego body masked);
    ``views="validation_views"``: the images the early-stop rule measured."""
    import torch

    from nuav2.evaluate.image_metrics import psnr
    from nuav2.recon import views_from_records
    from nuav2.splat.init import load_image

    records = splat.info.get(views) or []
    if not records:
        return None
    masks = {c.channel: c for c in scene.rig.cameras}
    vals = []
    for view in views_from_records(records):
        img = load_image(view.path, view.cam.width, view.cam.height)
        with torch.no_grad():
            out = splat.render(view.cam, view.city_T_cam, view.timestamp_ns).rgb.clamp(0, 1).cpu().numpy()
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


def _one_log(log_dir: Path, budgets: list[dict], holdout_every: int, n_times: int,
             progress: bool) -> list[dict]:
    """Every budget on one log (one reconstruction each, in order), scored in the target rig."""
    from converters.av2 import read_log
    from nuav2.recon import reconstruct
    from nuav2.synth import load_world

    scene = read_log(Path(log_dir))
    world = load_world(Path(log_dir))
    rows = []
    for b in budgets:
        cfg = config_for(b, holdout_every)
        sw = Stopwatch()
        with sw:
            splat = reconstruct(scene, cfg, progress=progress)
        train, init = splat.info.get("train") or {}, splat.info.get("init_stats") or {}
        row = {**b, "log_id": scene.log_id, "recon_s": sw.wall_s[0], "recon_cpu_s": sw.cpu_s[0],
               "load_1min_after_recon": sw.load[0], "final_gaussians": splat.num_gaussians(),
               "scene_budget": init.get("gaussian_budget"), "moving_tracks": init.get("moving_tracks"),
               "steps": train.get("steps"), "stop_reason": train.get("stop_reason"),
               "init_s": splat.info.get("init_seconds")}
        render = render_whole_log_s(splat, scene)
        row |= {"render_log_s": render.wall_s[0], "render_log_cpu_s": render.cpu_s[0],
                "frames": len(scene.sweep_timestamps_ns)}
        row["recon_plus_render_s"] = sw.wall_s[0] + render.wall_s[0]
        t1 = time.perf_counter()
        row["target"] = target_rig_scores(splat, scene, world, n_times=n_times)
        row["target_render_s"] = time.perf_counter() - t1
        row["heldout"] = heldout_psnr(splat, scene)
        rows.append(row)
    base = rows[0]
    for r in rows:
        r["time_ratio"] = r["recon_s"] / max(base["recon_s"], 1e-9)
        r["target_psnr_gain_db"] = r["target"]["psnr_db"] - base["target"]["psnr_db"]
    return rows


def bench_recon(log_dir: str | Path | None = None, *, seed: int = 0, seeds: tuple[int, ...] | None = None,
                presets: tuple[str, ...] = ("easy",), budgets: list[dict] | None = None,
                holdout_every: int = 5, n_times: int = 6, synth_overrides: dict | None = None,
                scenes: tuple[str | None, ...] = (None,), command: str | None = None,
                progress: bool = False) -> dict:
    """Speed-against-error rows for each (preset, seed, budget) in one process, and per (preset, budget)
    the mean and spread over the seeds the reconstruction presets were not tuned on.

    With ``log_dir`` (a synthetic log) only that log is measured; otherwise one log is generated per
    preset, scene (``SCENES``; None: the preset's own) and seed (``seeds``, default ``(seed,)``),
    ``synth_overrides`` changing its SynthConfig.
    """
    from nuav2.synth import SynthConfig, generate_log

    budgets = budgets or default_budgets()
    start = machine()
    rows: list[dict] = []
    gen_s: dict[str, float] = {}
    if log_dir is not None:
        for r in _one_log(Path(log_dir), budgets, holdout_every, n_times, progress):
            rows.append({"preset": None, "scene": None, "seed": None, "tuned": False, **r})
    else:
        for preset, scene_name, sd in itertools.product(presets, scenes, seeds or (seed,)):
            with tempfile.TemporaryDirectory(prefix="nuav2-bench-recon-") as tmp:
                t0 = time.perf_counter()
                overrides = {**(synth_overrides or {}), **SCENES.get(scene_name, {})}
                log = generate_log(Path(tmp), seed=sd, config=SynthConfig.for_preset(preset, **overrides))
                gen_s["/".join(str(x) for x in (preset, scene_name, sd) if x is not None)] = round(
                    time.perf_counter() - t0, 2)
                tuned = (preset, sd) in TUNED and scene_name is None
                for r in _one_log(log, budgets, holdout_every, n_times, progress):
                    rows.append({"preset": preset, "scene": scene_name, "seed": sd, "tuned": tuned, **r})
    return {"command": command, "interleaved": False, "machine_at_start": start,
            "load_1_5_15_at_end": machine()["load_1_5_15"], "generate_s": gen_s,
            "tuned_on": [{"preset": p, "seed": s} for p, s in sorted(TUNED)],
            "baseline": rows[0]["name"], "rows": rows, "over_seeds": over_seeds(rows)}


def _row_figures(r: dict) -> dict[str, float | None]:
    t = r["target"]
    return {**{f"psnr_{k}": v for k, v in t["regions"]["psnr_db"].items()},
            **{f"ssim_{k}": v for k, v in t["regions"]["ssim"].items()},
            "paint_px": (t.get("paint") or {}).get("median_px_render"),
            "paint_px_truth": (t.get("paint") or {}).get("median_px_truth"),
            "heldout_psnr": (r.get("heldout") or {}).get("psnr_db"),
            "recon_s": r["recon_s"], "recon_cpu_s": r["recon_cpu_s"],
            "final_gaussians": r.get("final_gaussians"), "steps": r.get("steps"),
            "render_s_per_frame": r["render_log_s"] / max(1, r["frames"])}


def over_seeds(rows: list[dict]) -> list[dict]:
    """Per (preset, scene, budget): the tuned seed's figures apart, and mean / sample std / min / max over
    the other seeds (std is None with one seed)."""
    out = []
    keys = list(dict.fromkeys((r["preset"], r.get("scene"), r["name"]) for r in rows))
    for preset, scene_name, name in keys:
        group = [r for r in rows if (r["preset"], r.get("scene"), r["name"]) == (preset, scene_name, name)]
        untuned = [_row_figures(r) for r in group if not r["tuned"]]
        entry: dict = {"preset": preset, "scene": scene_name, "budget": name,
                       "seeds": [r["seed"] for r in group if not r["tuned"]]}
        tuned = [r for r in group if r["tuned"]]
        if tuned:
            entry["tuned_seed"] = {"seed": tuned[0]["seed"], **_row_figures(tuned[0])}
        stats = {}
        for k in (untuned[0] if untuned else {}):
            v = np.array([u[k] for u in untuned if u[k] is not None], float)
            if len(v):
                stats[k] = {"mean": float(v.mean()), "std": float(v.std(ddof=1)) if len(v) > 1 else None,
                            "min": float(v.min()), "max": float(v.max())}
        entry["untuned"] = stats
        out.append(entry)
    return out


def plot_bench(result: dict, path: str | Path) -> None:
    """PNG of target-rig PSNR (whole image and ground) and held-out PSNR against reconstruction CPU time
    (all threads: on a shared machine wall time mostly measures the other jobs), one point per budget,
    for the first log of ``result`` (its preset and seed in the title)."""
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from nuav2.atomic import atomic_write_bytes

    first = result["rows"][0]
    rows = [r for r in result["rows"] if (r["preset"], r["seed"]) == (first["preset"], first["seed"])]
    t = [r["recon_cpu_s"] for r in rows]
    fig, ax = plt.subplots(figsize=(6.4, 4.0), dpi=110)
    ax.plot(t, [r["target"]["psnr_db"] for r in rows], "o-", label="target rig (nuScenes) vs truth")
    ax.plot(t, [r["target"]["regions"]["psnr_db"]["ground"] for r in rows], "^:", label="target rig, ground")
    held = [(r["recon_cpu_s"], r["heldout"]["psnr_db"]) for r in rows if r.get("heldout")]
    if held:
        ax.plot(*zip(*held), "s--", label="held-out source views")
    for r in rows:
        ax.annotate(r["name"], (r["recon_cpu_s"], r["target"]["psnr_db"]), textcoords="offset points",
                    xytext=(4, -12), fontsize=8)
    ax.set_xlabel("reconstruction CPU time (s, 2 threads together)")
    ax.set_ylabel("PSNR (dB)")
    ax.set_title(f"nuav2 bench recon, synthetic preset {first['preset']}, seed {first['seed']}")
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    plt.close(fig)
    atomic_write_bytes(Path(path), buf.getvalue())
