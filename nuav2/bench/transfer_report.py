"""Tables, ratios, verdicts and figures of ``nuav2 bench transfer`` (from its result dict).

Table 1 (paper shape): AP per class (mean over the 0.5 / 1.0 / 1.5 m thresholds) and mAP, x100,
per training set, mean +- sample standard deviation over training seeds; the per-threshold APs
are in a second table. Ratios nuAV2 / AV2 and nuAV2 / oracle sit next to the paper's 4.25x and
29 %. Table 2: fine-tuning on fractions of the oracle training set, from scratch vs pretrained
on nuAV2. The verdicts say whether the paper's orderings hold, on the means and per seed.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from nuav2.atomic import atomic_write_bytes
from nuav2.bench.transfer_config import PAPER_RATIOS, PAPER_TABLE1, PAPER_TABLE2, SET_LABELS

# mAP differences below this (0.1 point x100, the tables' resolution) are ties, not orderings
MAP_RESOLUTION = 0.001

CLASS_SHORT = {"divider": "Div.", "ped_crossing": "Cross.", "boundary": "Bound.", "centerline": "Center."}


def _stats(values: list[float]) -> dict:
    arr = np.asarray(values, dtype=np.float64)
    return {
        "mean": float(arr.mean()),
        "std": float(arr.std(ddof=1)) if len(arr) > 1 else 0.0,
        "min": float(arr.min()),
        "max": float(arr.max()),
        "values": [float(v) for v in arr],
    }


def _aggregate(runs: list[dict], classes: list[str], key: str = "eval") -> dict:
    thr = list(runs[0][key]["ap"][classes[0]])
    return {
        "n_seeds": len(runs),
        "keyframes": runs[0]["keyframes"],
        "scenes": runs[0]["scenes"],
        "mAP": _stats([r[key]["mAP"] for r in runs]),
        "bev_seg_ap": _stats([r["bev_seg"]["ap"] for r in runs]),
        "class_mean_ap": {c: _stats([r[key]["class_mean_ap"][c] for r in runs]) for c in classes},
        "ap": {c: {t: _stats([r[key]["ap"][c][t] for r in runs]) for t in thr} for c in classes},
    }


def _ratio(a: float, b: float) -> float | None:
    return a / b if b > 0 else None


def summarize(result: dict, eval_key: str = "eval") -> dict:
    """Tables, ratios and verdicts of one decoding: ``eval_key`` is the runs' ``nuav2 eval`` result to read
    (``eval``: the vector head, ``eval_seg``: traced from the BEV segmentation)."""
    cfg = result["config"]
    classes = list(cfg["model"]["classes"])
    runs = result["runs"]
    sets = [s for s in cfg["sets"] if any(r.get("set") == s for r in runs.values())]
    table1 = {s: _aggregate([r for r in runs.values() if r.get("set") == s], classes, eval_key) for s in sets}
    by_seed = {s: {r["seed"]: r[eval_key]["mAP"] for r in runs.values() if r.get("set") == s} for s in sets}
    ratios = {}
    for nu in ("render", "warp"):
        if nu not in table1:
            continue
        for ref, key in (("native", "over_av2"), ("truth", "over_oracle")):
            if ref not in table1:
                continue
            ratios[f"{nu}_{key}"] = {
                "of_means": _ratio(table1[nu]["mAP"]["mean"], table1[ref]["mAP"]["mean"]),
                "per_seed": {str(s): _ratio(by_seed[nu][s], by_seed[ref][s]) for s in cfg["seeds"]},
                "paper": PAPER_RATIOS["nuav2_over_av2" if ref == "native" else "nuav2_over_oracle"],
            }
    table2 = {}
    for frac in cfg["fractions"]:
        rows = {
            arm: [r for r in runs.values() if r.get("fraction") == frac and r.get("arm") == arm]
            for arm in ("scratch", "pretrained")
        }
        if all(rows.values()):
            table2[f"{frac:g}"] = {arm: _aggregate(v, classes, eval_key) for arm, v in rows.items()}
            table2[f"{frac:g}"]["paper_mAP"] = PAPER_TABLE2.get(frac)
    return {
        "table1": table1,
        "ratios": ratios,
        "table2": table2,
        "verdict": verdicts(table1, table2, by_seed),
    }


def verdicts(table1: dict, table2: dict, by_seed: dict) -> dict:
    """Does the paper's ordering hold? oracle > nuAV2 > AV2 on the test worlds; pretraining helps."""
    out: dict = {}
    m = {s: v["mAP"]["mean"] for s, v in table1.items()}
    bev = {s: v["bev_seg_ap"]["mean"] for s, v in table1.items()}
    for nu in ("render", "warp"):
        if {nu, "native", "truth"} <= set(m):
            seeds = sorted(by_seed[nu])
            out[f"oracle_gt_{nu}_gt_av2"] = {
                "on_means": m["truth"] - m[nu] >= MAP_RESOLUTION and m[nu] - m["native"] >= MAP_RESOLUTION,
                # False: every mean below the tables' resolution, so no ordering can be read at all
                "measurable": max(m["truth"], m[nu], m["native"]) >= MAP_RESOLUTION,
                "seeds_holding": sum(
                    by_seed["truth"][s] > by_seed[nu][s] > by_seed["native"][s] for s in seeds
                ),
                "seeds": len(seeds),
                "gain_over_av2_mAP": m[nu] - m["native"],
                "gap_to_oracle_mAP": m["truth"] - m[nu],
                # the same ordering on the BEV segmentation diagnostic (informative where mAP is ~0)
                "bev_seg_ap_on_means": bev["truth"] > bev[nu] > bev["native"],
                "bev_seg_ap": {s: bev[s] for s in ("native", nu, "truth")},
            }
    if table2:
        out["pretraining_helps"] = {
            f: {
                "gain_mAP": row["pretrained"]["mAP"]["mean"] - row["scratch"]["mAP"]["mean"],
                "holds": row["pretrained"]["mAP"]["mean"] - row["scratch"]["mAP"]["mean"] >= MAP_RESOLUTION,
                "measurable": max(row["pretrained"]["mAP"]["mean"], row["scratch"]["mAP"]["mean"])
                >= MAP_RESOLUTION,
                "seeds_holding": sum(
                    p > s for p, s in zip(row["pretrained"]["mAP"]["values"], row["scratch"]["mAP"]["values"])
                ),
            }
            for f, row in table2.items()
        }
    return out


def _pm(s: dict, scale: float = 100.0) -> str:
    return f"{s['mean'] * scale:.1f} ± {s['std'] * scale:.1f}" if s.get("std") else f"{s['mean'] * scale:.1f}"


def _fmt_ratio(r: dict, percent: bool) -> str:
    def one(x):
        return "n/a (denominator 0)" if x is None else (f"{100 * x:.0f} %" if percent else f"{x:.2f}x")

    seeds = ", ".join(one(v) for v in r["per_seed"].values())
    paper = f"{100 * r['paper']:.0f} %" if percent else f"{r['paper']:.2f}x"
    return f"{one(r['of_means'])} (per seed: {seeds}; paper: {paper})"


DECODING_LABELS = {
    "vector": "the vector head",
    "seg": "polylines traced from the BEV segmentation",
}


def format_tables(result: dict) -> str:
    """Both decodings' tables and verdicts (the seg one when the result has it: ``seg_decoded``)."""
    text = _format_decoding(result, "vector")
    if result.get("seg_decoded"):
        text += "\n\n" + _format_decoding({**result, **result["seg_decoded"]}, "seg")
    return text


def _format_decoding(result: dict, decoding: str) -> str:
    cfg = result["config"]
    classes = list(cfg["model"]["classes"])
    t1 = result["table1"]
    head = (
        "| training set | keyframes | "
        + " | ".join(CLASS_SHORT.get(c, c) for c in classes)
        + " | mAP | BEV-seg AP (diagnostic) |"
    )
    sep = "|" + "---|" * (len(classes) + 4)
    lines = [
        f"### Decoded by {DECODING_LABELS[decoding]}",
        "",
        f"Table 1 shape: AP x100 on the test worlds' truth in the {cfg['target_rig']} rig "
        f"(mean ± std over seeds {list(cfg['seeds'])}; AP per class = mean over "
        f"{', '.join(map(str, result['runs'][next(iter(result['runs']))]['eval']['ap'][classes[0]]))} m)",
        "",
        head,
        sep,
    ]
    for s, row in t1.items():
        lines.append(
            f"| {SET_LABELS[s]} | {row['keyframes']} | "
            + " | ".join(_pm(row["class_mean_ap"][c]) for c in classes)
            + f" | **{_pm(row['mAP'])}** | {_pm(row['bev_seg_ap'])} |"
        )
    for s, paper in PAPER_TABLE1.items():
        lines.append(
            f"| paper: {SET_LABELS[s]} | | "
            + " | ".join(f"{paper[c]:.1f}" for c in classes)
            + f" | {paper['mAP']:.1f} | |"
        )
    thr = list(next(iter(t1.values()))["ap"][classes[0]])
    lines += [
        "",
        "AP x100 per threshold (mean over seeds):",
        "",
        "| training set | "
        + " | ".join(f"{CLASS_SHORT.get(c, c)} @{t}" for c in classes for t in thr)
        + " |",
        "|---|" + "---|" * (len(classes) * len(thr)),
    ]
    for s, row in t1.items():
        lines.append(
            f"| {SET_LABELS[s]} | "
            + " | ".join(f"{100 * row['ap'][c][t]['mean']:.1f}" for c in classes for t in thr)
            + " |"
        )
    if result.get("prior_only"):
        vals = [v["mAP" if decoding == "vector" else "seg_mAP"] for v in result["prior_only"].values()]
        lines += [
            "",
            f"Prior only (oracle models on flat grey test images): mAP {100 * np.mean(vals):.1f} "
            f"(per seed {', '.join(f'{100 * v:.1f}' for v in vals)})",
        ]
    lines += ["", "Ratios (mAP):", ""]
    for key, r in result["ratios"].items():
        lines.append(f"- {key.replace('_', ' ')}: {_fmt_ratio(r, 'oracle' in key)}")
    if result["table2"]:
        lines += [
            "",
            f"Table 2 shape: fine-tuning on a fraction of the oracle training set "
            f"({cfg['finetune_steps']} steps each arm; pretrained = the {SET_LABELS[cfg['pretrain_set']]} "
            f"model of the same seed), AP x100:",
            "",
            "| fraction | scenes / keyframes | pretrained | "
            + " | ".join(CLASS_SHORT.get(c, c) for c in classes)
            + " | mAP | paper mAP |",
            "|" + "---|" * (len(classes) + 5),
        ]
        for f, row in result["table2"].items():
            for i, arm in enumerate(("scratch", "pretrained")):
                a = row[arm]
                paper = row.get("paper_mAP")
                lines.append(
                    f"| {100 * float(f):g} % | {a['scenes']} / {a['keyframes']} | "
                    f"{'yes' if arm == 'pretrained' else 'no'} | "
                    + " | ".join(_pm(a["class_mean_ap"][c]) for c in classes)
                    + f" | **{_pm(a['mAP'])}** | "
                    + (f"{paper[i]:.1f}" if paper else "–")
                    + " |"
                )
    lines += ["", "Verdict:", ""] + [f"- {v}" for v in verdict_lines(result)]
    return "\n".join(lines)


def _holds(v: dict) -> str:
    if not v["measurable"]:
        return "does NOT hold (not measurable: every mAP below 0.1)"
    return "holds" if v["on_means"] else "does NOT hold"


def verdict_lines(result: dict) -> list[str]:
    out = []
    for key, v in result["verdict"].items():
        if key.startswith("oracle_gt_"):
            nu = key.split("_")[2]
            out.append(
                f"oracle > nuAV2 ({nu}) > AV2: {_holds(v)} on the means "
                f"({v['seeds_holding']} of {v['seeds']} seeds); "
                f"nuAV2 - AV2 = {100 * v['gain_over_av2_mAP']:+.1f} mAP, "
                f"oracle - nuAV2 = {100 * v['gap_to_oracle_mAP']:+.1f} mAP; on the BEV-seg AP diagnostic "
                f"{'holds' if v['bev_seg_ap_on_means'] else 'does NOT hold'} (AV2 "
                f"{100 * v['bev_seg_ap']['native']:.1f}, nuAV2 {100 * v['bev_seg_ap'][nu]:.1f}, oracle "
                f"{100 * v['bev_seg_ap']['truth']:.1f})"
            )
        elif key == "pretraining_helps":
            for f, p in v.items():
                out.append(
                    f"pretraining on nuAV2 at {100 * float(f):g} %: "
                    f"{'helps' if p['holds'] else 'does NOT help'}"
                    f"{'' if p['measurable'] else ' (every mAP below 0.1: not measurable)'} "
                    f"({100 * p['gain_mAP']:+.1f} mAP, {p['seeds_holding']} of "
                    f"{len(result['config']['seeds'])} seeds)"
                )
    return out


def write_markdown(result: dict, path: Path) -> None:
    t = result["timing"]
    text = (
        f"# nuav2 bench transfer ({result['config']['size']})\n\n"
        f"Command: `{result['command']}`  \npreset `{result['config']['preset']}`, "
        f"{result['config']['train_worlds']} train / {result['config']['test_worlds']} test worlds of "
        f"{result['config']['seconds']} s, seeds {list(result['config']['seeds'])}; "
        f"wall {t['wall_s'] / 60:.1f} min, "
        f"load {t['load_avg_start'][0]:.1f} -> {t['load_avg_end'][0]:.1f}\n\n{format_tables(result)}\n"
    )
    atomic_write_bytes(path, text.encode())


def plot_curves(result: dict, path: Path) -> Path:
    """mAP against training steps: one line per training set (mean over seeds, band = min..max),
    and the fine-tuning runs in a second panel."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cfg = result["config"]
    fig, axes = plt.subplots(
        1, 2 if result["table2"] else 1, figsize=(11 if result["table2"] else 6, 4), squeeze=False
    )
    ax = axes[0, 0]
    for s in cfg["sets"]:
        curves = [r["curve"] for r in result["runs"].values() if r.get("set") == s and r["curve"]]
        if not curves:
            continue
        steps = [p["step"] for p in curves[0]]
        colour = None
        for key, style, label in (("mAP", "-", ""), ("seg_mAP", "--", " (seg-traced)")):
            if any(key not in p for c in curves for p in c):
                continue
            vals = np.array([[p[key] * 100 for p in c] for c in curves if len(c) == len(steps)])
            line = ax.plot(steps, vals.mean(0), style, marker="o", color=colour, label=SET_LABELS[s] + label)
            colour = line[0].get_color()
            ax.fill_between(steps, vals.min(0), vals.max(0), alpha=0.15, color=colour)
    ax.set(
        xlabel="training step",
        ylabel="mAP x100 (test worlds, target rig)",
        title="Table 1 runs (solid: vector head, dashed: seg-traced)",
    )
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    if result["table2"]:
        ax = axes[0, 1]
        for f in cfg["fractions"]:
            for arm, style in (("scratch", "--"), ("pretrained", "-")):
                curves = [
                    r["curve"]
                    for r in result["runs"].values()
                    if r.get("fraction") == f and r.get("arm") == arm and r["curve"]
                ]
                if curves:
                    steps = [p["step"] for p in curves[0]]
                    vals = np.array([[p["mAP"] * 100 for p in c] for c in curves if len(c) == len(steps)])
                    ax.plot(steps, vals.mean(0), style, marker="o", label=f"{100 * f:g} % {arm}")
        ax.set(xlabel="fine-tuning step", ylabel="mAP x100", title="Table 2 runs (oracle subsets)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    import io

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())
    return path


def write_figures(result: dict, out: Path, test) -> dict:
    """curves.png, and ``nuav2 viz --pred`` pictures of one test keyframe for the first seed's runs."""
    import contextlib
    import io

    from nuav2.cli import main

    figs = {"curves": str(plot_curves(result, out / "curves.png")), "pred_vs_gt": {}}
    token = test.data.tokens[len(test.data) // 2]
    seed = result["config"]["seeds"][0]
    for s in result["config"]["sets"]:
        pred = Path(result["runs"][f"{s}-s{seed}"]["run_dir"]) / "predictions.json"
        png = out / f"pred_vs_gt_{s}.png"
        with contextlib.redirect_stdout(io.StringIO()):
            rc = main(
                [
                    "viz",
                    str(test.dataroot),
                    "--version",
                    result["config"]["version"],
                    "--sample",
                    token,
                    "--out",
                    str(png),
                    "--pred",
                    str(pred),
                    "--tile-height",
                    "180",
                ]
            )
        if rc == 0:
            figs["pred_vs_gt"][s] = str(png)
    figs["sample_token"] = token
    return figs
