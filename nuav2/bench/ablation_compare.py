"""Two realism ablations side by side (``nuav2 bench ablation --from-json AFTER --before BEFORE``).

The ablation (``nuav2.bench.ablation``) measures what each realism factor costs warp and render mode:
a row's score minus the ``easy`` row of the same seed. Run once before the robustness work and once
after, the two JSON files give, per factor and mode, the dB lost before and after and the share of it
recovered; the goals of the robustness issue are evaluated on the same numbers:

- each of ``exposure``, ``label_noise``, ``lidar_noise``: at least two thirds of its loss recovered;
- ``exposure`` alone costs less than 0.5 dB after, judged on the raw PSNR and, beside it, on the PSNR
  after one gain per colour channel per log (``psnr_gauge_db``, fitted to the truth) and on the PSNR
  after the log's true mean exposure is taken out (``psnr_ref_db``, from the cameras' recorded gains,
  nothing fitted): harmonised images sit at the log's mean exposure, whose offset from the world's unit
  exposure no image can reveal;
- the same on the ``+exposure_gains`` row (drifting gains, white balance and vignetting without the
  sensor noise and JPEG compression that no gain removes): exposure drift alone;
- on ``hard``, render mode's ground-region PSNR within 2 dB of its ``easy`` figure.
"""

from __future__ import annotations

import copy

MODES = ("warp", "render")
RECOVER_FACTORS = ("exposure", "label_noise", "lidar_noise")
RECOVER_SHARE = 2.0 / 3.0
EXPOSURE_MAX_LOSS_DB = 0.5
HARD_GROUND_MAX_GAP_DB = 2.0
GAUGES = (("psnr_db", ""), ("psnr_gauge_db", ", one gain per colour channel per log removed"),
          ("psnr_ref_db", ", the log's true mean exposure taken out (nothing fitted)"))


def lost_db(result: dict, row: str, mode: str, region: str = "whole",
            metric: str = "psnr_db") -> float | None:
    """dB the row loses against easy (mean over seeds; positive = worse than easy), or None if not run."""
    d = result["rows"].get(row, {}).get(mode, {}).get("delta", {}).get(f"{metric}_{region}")
    return None if d is None else -float(d)


def merge_modes(results: list[dict]) -> dict:
    """One result from several saved runs of the same rows and seeds: each later run's modes replace the
    earlier ones' (a warp-only rerun after a warp change, the render columns kept). Raises ValueError where
    the rows' seeds differ (the deltas would not be of the same worlds)."""
    merged = copy.deepcopy(results[0])
    for later in results[1:]:
        for row, rec in later["rows"].items():
            if row not in merged["rows"]:
                merged["rows"][row], merged["per_seed"][row] = copy.deepcopy(rec), copy.deepcopy(
                    later["per_seed"][row])
                continue
            if _seeds(merged, row) != _seeds(later, row):
                raise ValueError(f"row {row}: seeds {_seeds(later, row)} differ from {_seeds(merged, row)}")
            for mode in MODES:
                if mode in rec:
                    merged["rows"][row][mode] = copy.deepcopy(rec[mode])
                    for mine, theirs in zip(merged["per_seed"][row], later["per_seed"][row]):
                        mine.setdefault("modes", {})[mode] = copy.deepcopy(theirs["modes"][mode])
        merged["command"] = f"{merged['command']}` + `{later['command']}"
        merged["machine_end"] = later["machine_end"]
    return merged


def recovered_share(before: float | None, after: float | None) -> float | None:
    """Share of a loss recovered; None when either side is missing or there was no loss to recover."""
    if before is None or after is None or before <= 0.05:
        return None
    return (before - after) / before


def _seeds(result: dict, row: str) -> list[int]:
    return list(result["rows"].get(row, {}).get("seeds", []))


def goals(before: dict, after: dict) -> list[dict]:
    """Each goal with the figures it was judged on and whether it is met (None: not measured)."""
    out = []
    for f in RECOVER_FACTORS:
        for mode in MODES:
            b, a = lost_db(before, f"+{f}", mode), lost_db(after, f"+{f}", mode)
            share = recovered_share(b, a)
            met = None if b is None or a is None else (
                a <= 0.05 or (share is not None and share >= RECOVER_SHARE))
            out.append({"goal": f"recover >= 2/3 of the dB {f} costs", "mode": mode, "lost_before_db": b,
                        "lost_after_db": a, "recovered_share": share, "met": met})
    for mode in MODES:
        for metric, what in GAUGES:
            a = lost_db(after, "+exposure_gains", mode, metric=metric)
            out.append({"goal": "exposure drift alone (gains, no sensor noise) costs < "
                                f"{EXPOSURE_MAX_LOSS_DB} dB after compensation{what}",
                        "mode": mode, "lost_after_db": a,
                        "met": None if a is None else a < EXPOSURE_MAX_LOSS_DB})
        for metric, what in GAUGES:
            a = lost_db(after, "+exposure", mode, metric=metric)
            out.append({"goal": f"exposure alone costs < {EXPOSURE_MAX_LOSS_DB} dB after compensation{what}",
                        "mode": mode, "lost_after_db": a,
                        "met": None if a is None else a < EXPOSURE_MAX_LOSS_DB})
    gap = lost_db(after, "hard", "render", "ground")
    out.append({"goal": f"hard: render ground PSNR within {HARD_GROUND_MAX_GAP_DB} dB of easy",
                "mode": "render", "lost_after_db": gap,
                "lost_before_db": lost_db(before, "hard", "render", "ground"),
                "met": None if gap is None else gap <= HARD_GROUND_MAX_GAP_DB})
    return out


def _f(v: float | None, spec: str = ".2f") -> str:
    return "–" if v is None else format(v, spec)


def _load(result: dict) -> str:
    a, b = result["machine_start"]["load_1_5_15"][0], result["machine_end"]["load_1_5_15"][0]
    return f"load (1 min) {a:.1f} at the start, {b:.1f} at the end"


def compare_markdown(before: dict, after: dict) -> str:
    """Per row: dB lost against easy (whole image and ground) before and after, per mode; then the goals."""
    rows = list(dict.fromkeys([*before["rows"], *after["rows"]]))
    head = ["row"]
    for mode in MODES:
        head += [f"{mode}: dB lost before → after (recovered)", f"{mode}: ground dB lost before → after"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row in rows:
        if row == "easy":
            cells = ["easy (PSNR dB, before → after)"]
            for mode in MODES:
                pb = before["rows"]["easy"].get(mode, {})
                pa = after["rows"].get("easy", {}).get(mode, {})
                cells += [f"{_f(pb.get('psnr_db_whole'))} → {_f(pa.get('psnr_db_whole'))}",
                          f"{_f(pb.get('psnr_db_ground'))} → {_f(pa.get('psnr_db_ground'))}"]
            lines.append("| " + " | ".join(cells) + " |")
            continue
        cells = [row]
        for mode in MODES:
            b, a = lost_db(before, row, mode), lost_db(after, row, mode)
            share = recovered_share(b, a)
            gb, ga = lost_db(before, row, mode, "ground"), lost_db(after, row, mode, "ground")
            cells += [f"{_f(b)} → {_f(a)}" + (f" ({share:.0%})" if share is not None else ""),
                      f"{_f(gb)} → {_f(ga)}"]
        lines.append("| " + " | ".join(cells) + " |")
    seeds_b, seeds_a = _seeds(before, "easy"), _seeds(after, "easy")
    lines += ["", f"Before: `{before['command']}` (seeds {seeds_b}; {_load(before)}, "
                  f"{before['machine_start']['cpu_count']} cores). After: `{after['command']}` "
                  f"(seeds {seeds_a}; {_load(after)}). {after['how']}. dB lost = easy row minus the "
                  "factor's row of the same seed, mean over seeds; recovered = (before - after) / before.",
              ""]
    lines += ["| goal | mode | before | after | met |", "|---|---|---|---|---|"]
    for g in goals(before, after):
        share = g.get("recovered_share")
        after_txt = _f(g.get("lost_after_db")) + (f" ({share:.0%} recovered)" if share is not None else "")
        met = {True: "yes", False: "**no**", None: "not measured"}[g["met"]]
        lines.append(f"| {g['goal']} | {g['mode']} | {_f(g.get('lost_before_db'))} | {after_txt} | {met} |")
    return "\n".join(lines) + "\n"
