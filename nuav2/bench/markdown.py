"""Markdown tables of the ``bench modes`` and ``bench recon`` JSON, exactly as the docs print them.

Each table is preceded by how it was measured (the command, interleaved or not, the load, the log
lengths), so a table pasted into the docs carries its own provenance.
"""

from __future__ import annotations

REGIONS = ("whole", "ground", "objects", "sky", "nonrigid")


def _f(v: float | None, spec: str = ".2f") -> str:
    return "–" if v is None else format(v, spec)


def _table(header: list[str], rows: list[list[str]]) -> str:
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(out)


def _load(result: dict) -> str:
    return (f"load (1/5/15 min) {result['machine_at_start']['load_1_5_15']} at start, "
            f"{result['load_1_5_15_at_end']} at end, {result['machine_at_start']['cpu_count']} cores")


def _over_seeds(values: list[float | None], spec: str) -> str:
    """One value, or mean ± std (population) over seeds."""
    vals = [v for v in values if v is not None]
    if not vals:
        return "–"
    if len(vals) == 1:
        return format(vals[0], spec)
    mean = sum(vals) / len(vals)
    std = (sum((v - mean) ** 2 for v in vals) / len(vals)) ** 0.5
    return f"{mean:{spec}} ± {std:{spec}}"


def _cells(by_preset: dict[str, list[dict]], get, spec: str = ".2f") -> str:
    """One cell per preset, joined by " / ": ``get(run)`` over that preset's runs (seeds)."""
    return " / ".join(_over_seeds([get(r) for r in runs], spec) for runs in by_preset.values())


def modes_markdown(result: dict) -> str:
    """Quality per candidate with the presets side by side (one table per log length; over several seeds a
    cell is mean ± std), then timing per log."""
    runs = result["runs"]
    parts = [f"Measured with `{result['command']}` (candidates interleaved frame by frame in one process; "
             f"{_load(result)})."]
    for seconds in dict.fromkeys(r["seconds"] for r in runs):
        group = [r for r in runs if r["seconds"] == seconds]
        presets = list(dict.fromkeys(r["preset"] for r in group))
        by_preset = {p: [r for r in group if r["preset"] == p] for p in presets}
        seeds = sorted({r["seed"] for r in group})
        first = group[0]
        tw, th = first["target"]["image_size"]
        sw, sh = first["source_image_size"]
        over = (f", mean ± std over seeds {', '.join(map(str, seeds))}" if len(seeds) > 1
                else f", seed {seeds[0]}")
        parts.append(f"Quality, {seconds:g} s log ({first['frames']} frames x {first['images_per_frame']} "
                     f"target cameras at {tw}x{th}, source cameras {sw}x{sh}{over}); each cell "
                     f"{' / '.join(presets)}:")
        header = ["candidate", *[f"PSNR {g} dB" for g in REGIONS], "SSIM whole", "SSIM ground",
                  "lane paint px"]
        rows = []
        for m in first["modes"]:
            rows.append([m.replace("_", " "),
                         *[_cells(by_preset, lambda r, m=m, g=g: r["modes"][m]["quality"]["psnr_db"][g])
                           for g in REGIONS],
                         _cells(by_preset, lambda r, m=m: r["modes"][m]["quality"]["ssim"]["whole"], ".3f"),
                         _cells(by_preset, lambda r, m=m: r["modes"][m]["quality"]["ssim"]["ground"], ".3f"),
                         _cells(by_preset, lambda r, m=m: r["modes"][m]["quality"]["paint_median_px"])])
        rows.append(["ground truth (paint floor)", *["–"] * (len(REGIONS) + 2),
                     _cells(by_preset, lambda r: r["paint_floor_median_px"])])
        parts.append(_table(header, rows))
    header = ["log", "frames", "rotation s/frame", "warp s/frame", "render s/frame",
              "render / warp per frame", "reconstruction s", "warp amortised s/frame",
              "render amortised s/frame", "render / warp amortised", "load during frames"]
    rows = []
    for r in runs:
        m = r["modes"]

        def wc(d: dict, a: str = "wall_s_mean", b: str = "cpu_s_mean") -> str:
            return f"{d[a]:.3f} ({d[b]:.3f})"

        seed = f", seed {r['seed']}" if len({x["seed"] for x in runs}) > 1 else ""
        warp_amortised = wc(m["warp"]["amortised_per_frame"], "wall_s", "cpu_s")
        if "render" in m:
            ratio = r["ratios"]
            per_frame = [wc(m["render"]["per_frame"]), f"{ratio['render_over_warp_per_frame_wall']:.1f}x "
                                                       f"({ratio['render_over_warp_per_frame_cpu']:.1f}x)",
                         f"{m['render']['setup']['wall_s']:.0f} ({m['render']['setup']['cpu_s']:.0f})"]
            amortised = [wc(m["render"]["amortised_per_frame"], "wall_s", "cpu_s"),
                         f"{ratio['render_over_warp_amortised_wall']:.1f}x "
                         f"({ratio['render_over_warp_amortised_cpu']:.1f}x)"]
        else:  # --no-render: the rotation and warp timings alone
            per_frame, amortised = ["–"] * 3, ["–"] * 2
        rows.append([f"{r['preset']}, {r['seconds']:g} s{seed}", str(r["frames"]),
                     wc(m["rotation"]["per_frame"]), wc(m["warp"]["per_frame"]), *per_frame, warp_amortised,
                     *amortised, "–".join(f"{x:.1f}" for x in m["warp"]["per_frame"]["load_1min"])])
    if rows:
        parts.append("Time, wall seconds (CPU seconds of all threads in parentheses); one frame = all target "
                     f"cameras at one sweep; reconstruction preset `{runs[0]['recon_preset']}`:")
        parts.append(_table(header, rows))
    return "\n\n".join(parts) + "\n"


def _spread(stats: dict, key: str, spec: str = ".2f") -> str:
    s = stats.get(key)
    if not s:
        return "–"
    std = "" if s["std"] is None else f" ± {s['std']:{spec}}"
    return f"{s['mean']:{spec}}{std}"


def _log_name(preset: str | None, scene: str | None) -> str:
    return f"{preset}" + (f", scene {scene}" if scene else "")


def _steps(r: dict) -> str:
    if r.get("steps") is None:
        return str(r["iterations"])
    stop = {"plateau": ", stopped", "time budget": ", time budget"}.get(r.get("stop_reason"), "")
    return f"{r['iterations']} ({r['steps']}{stop})"


def recon_markdown(result: dict) -> str:
    """Per log: the budgets' rows; then, per preset and budget, the tuned seed against the unseen seeds;
    then, with scene variants, the scenes side by side (Gaussians, iterations, seconds, PSNR)."""
    parts = [f"Measured with `{result['command']}` (reconstructions one after another in one process; "
             f"{_load(result)})."]
    logs = list(dict.fromkeys((r["preset"], r.get("scene"), r["seed"]) for r in result["rows"]))
    header = ["budget", "iterations cap (run)", "Gaussians (final)", "train width", "recon s wall (CPU)",
              "render s/frame wall (CPU)", *[f"PSNR {g}" for g in REGIONS], "SSIM whole", "SSIM ground",
              "held-out PSNR", "paint px (truth)"]
    for preset, scene, seed in logs:
        rows = []
        for r in result["rows"]:
            if (r["preset"], r.get("scene"), r["seed"]) != (preset, scene, seed):
                continue
            t = r["target"]
            paint = t.get("paint") or {}
            budget = f"{r['gaussians'] // 1000}k ({r['final_gaussians'] // 1000}k)"
            rows.append([r["name"], _steps(r), budget, str(r["train_width_px"]),
                         f"{r['recon_s']:.0f} ({r['recon_cpu_s']:.0f})",
                         f"{r['render_log_s'] / max(1, r['frames']):.2f} "
                         f"({r['render_log_cpu_s'] / max(1, r['frames']):.2f})",
                         *[_f(t["regions"]["psnr_db"][g]) for g in REGIONS],
                         _f(t["regions"]["ssim"]["whole"], ".3f"), _f(t["regions"]["ssim"]["ground"], ".3f"),
                         _f((r.get("heldout") or {}).get("psnr_db")),
                         f"{_f(paint.get('median_px_render'))} ({_f(paint.get('median_px_truth'))})"])
        tuned = " (the seed the reconstruction presets were tuned on)" if (preset, seed) in {
            (x["preset"], x["seed"]) for x in result["tuned_on"]} and not scene else ""
        parts.append(f"Preset `{_log_name(preset, scene)}`, seed {seed}{tuned}:")
        parts.append(_table(header, rows))
    multi = [e for e in result["over_seeds"] if e["seeds"]]
    if multi:
        header = ["preset", "budget", "unseen seeds", *[f"PSNR {g}" for g in REGIONS], "SSIM whole",
                  "SSIM ground", "held-out PSNR", "paint px (truth)", "recon CPU s",
                  "tuned seed: PSNR whole / ground"]
        rows = []
        for e in multi:
            u = e["untuned"]
            ts = e.get("tuned_seed")
            tuned = f"{_f(ts['psnr_whole'])} / {_f(ts['psnr_ground'])} (seed {ts['seed']})" if ts else "–"
            rows.append([_log_name(e["preset"], e.get("scene")), e["budget"], ",".join(map(str, e["seeds"])),
                         *[_spread(u, f"psnr_{g}") for g in REGIONS], _spread(u, "ssim_whole", ".3f"),
                         _spread(u, "ssim_ground", ".3f"), _spread(u, "heldout_psnr"),
                         f"{_spread(u, 'paint_px')} ({_spread(u, 'paint_px_truth')})",
                         _spread(u, "recon_cpu_s", ".0f"),
                         tuned])
        parts.append("Over seeds (mean ± sample standard deviation over the unseen seeds; the tuned seed "
                     "apart):")
        parts.append(_table(header, rows))
    scened = [r for r in result["rows"] if r.get("scene")]
    if scened:
        header = ["scene", "seed", "budget", "scene Gaussian budget", "Gaussians (final)", "iterations run",
                  "recon s wall (CPU)", "target PSNR whole", "target PSNR ground", "held-out source PSNR"]
        rows = [[r["scene"], str(r["seed"]), r["name"], str(r.get("scene_budget")), str(r["final_gaussians"]),
                 _steps(r), f"{r['recon_s']:.0f} ({r['recon_cpu_s']:.0f})", _f(r["target"]["psnr_db"]),
                 _f(r["target"]["regions"]["psnr_db"]["ground"]), _f((r.get("heldout") or {}).get("psnr_db"))]
                for r in scened]
        parts.append("Scenes side by side (what the scene budget and the patience rule spend on each):")
        parts.append(_table(header, rows))
    return "\n\n".join(parts) + "\n"
