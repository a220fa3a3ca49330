"""``nuav2 bench transfer``: the MapGS paper's Tables 1 and 2 rerun end to end on synthetic worlds.

Does re-rendering AV2 into the target rig close the camera-rig gap? Here the target rig's true
images exist (the synthetic world renders them exactly), so the paper's logic can run on one
machine: train the small mapping model (:mod:`nuav2.mapping`) on the training worlds as AV2 has
them (native rig), as nuAV2 (warp and render into the nuScenes rig) and as the target rig's
truth (the oracle), and score every model with ``nuav2 eval`` on held-out test worlds' truth
in the nuScenes rig (Table 1, over several training seeds). Then fine-tune on 5 / 10 / 25 % of
the oracle training set from scratch and from the nuAV2 model (Table 2).

Everything lands under one output folder and is reused on a rerun (worlds, conversions, cached
tensors, finished runs, their evaluations), so an interrupted benchmark resumes; a changed
setting redoes only what depends on it (keys are config fingerprints).
"""

from __future__ import annotations

import json
import logging
import os
import time
from dataclasses import replace
from pathlib import Path

import torch

from nuav2.atomic import atomic_write_json
from nuav2.bench.transfer_config import TransferConfig
from nuav2.bench.transfer_data import prepare_data, test_source
from nuav2.bench.transfer_jobs import RunJob, run_jobs, train_tensors
from nuav2.mapping import (
    MapTensors,
    TrainConfig,
    bev_seg_scores,
    load_map_tensors,
    load_model,
    predict,
    predict_from_seg,
    score_in_process,
    score_with_nuav2_eval,
    train,
    write_results,
)

log = logging.getLogger(__name__)

RESULT_FILE = "transfer.json"
# per decoding of a model: its MapTR result file and the nuav2 eval result on it
DECODINGS = {
    "vector": ("predictions.json", "eval.json"),  # the vector head (MapTR's decoding)
    "seg": ("predictions_seg.json", "eval_seg.json"),  # polylines traced from the BEV segmentation
}
EVAL_KEYS = ("ap", "class_mean_ap", "map_per_threshold", "mAP", "num_gts", "num_preds", "n_samples")
_CURVE_KEYS = ("mAP", "class_mean_ap", "map_per_threshold")


def train_config(cfg: TransferConfig, steps: int, seed: int, eval_points: int) -> TrainConfig:
    return TrainConfig(
        steps=steps,
        batch_size=cfg.batch_size,
        lr=cfg.lr,
        seed=seed,
        threads=cfg.threads,
        eval_every=max(1, steps // max(1, eval_points)),
        checkpoint_every=max(1, min(250, steps)),
    )


class TestSet:
    """The test worlds' truth: tensors for the model, GT vectors for the in-training curve, and where
    ``nuav2 eval`` finds the same GT (dataroot, version, split)."""

    def __init__(self, cfg: TransferConfig, out: Path) -> None:
        from nuav2.maptr.vectorize import gt_vectors_for_split

        self.cfg = cfg
        self.dataroot, self.split = test_source(cfg, out)
        self.data = load_map_tensors(
            self.dataroot, cfg.version, self.split, cfg.model, cache_dir=out / "cache"
        )
        self.gts = gt_vectors_for_split(self.dataroot, cfg.version, self.split, patch=tuple(cfg.model.patch))

    def curve_point(self, model, data: MapTensors | None = None) -> dict:
        """Both decodings' scores on ``data`` (default: the test set; ``seg_mAP``: traced from the
        BEV segmentation)."""
        data = self.data if data is None else data
        r = score_in_process(predict(model, data), self.gts, self.cfg.model.classes)
        seg = score_in_process(predict_from_seg(model, data), self.gts, self.cfg.model.classes)
        return {**{k: r[k] for k in _CURVE_KEYS}, "seg_mAP": seg["mAP"]}

    def blank(self) -> MapTensors:
        """The test set with every image a flat grey: what a model predicts from its prior alone."""
        return replace(self.data, img=torch.full_like(self.data.img, 128))


def run_and_score(
    cfg: TransferConfig,
    name: str,
    run_dir: Path,
    data: MapTensors,
    tcfg: TrainConfig,
    test: TestSet,
    init: Path | None = None,
) -> dict:
    """Train (or reuse) one run, write its MapTR result file on the test set, score it with ``nuav2 eval``."""
    log.info(
        "run %s: %d keyframes, %d steps%s", name, len(data), tcfg.steps, f", from {init}" if init else ""
    )
    info = train(cfg.model, tcfg, data, run_dir, init_weights=init, evaluator=test.curve_point)
    results, model = {}, None
    for decoding, (pred_file, eval_file) in DECODINGS.items():
        eval_path = run_dir / eval_file
        result = json.loads(eval_path.read_text()) if eval_path.is_file() else {}
        if result.get("run_fingerprint") != info["fingerprint"]:
            model = load_model(run_dir) if model is None else model
            preds = predict(model, test.data) if decoding == "vector" else predict_from_seg(model, test.data)
            pred_path = write_results(
                run_dir / pred_file, preds, cfg.model.classes, {"run": name, "decoding": decoding}
            )
            result = score_with_nuav2_eval(
                pred_path, test.dataroot, cfg.version, test.split, cfg.model.classes, eval_path,
                patch=cfg.model.patch,
            )
            result["run_fingerprint"] = info["fingerprint"]
            torch.set_num_threads(tcfg.threads)  # nuav2 eval's numba kernels reset it (see mapping.train)
            if decoding == "vector":  # the diagnostic, not part of nuav2 eval
                result["bev_seg"] = bev_seg_scores(model, test.data)
            atomic_write_json(eval_path, result, indent=1)
        results[decoding] = result
    last = info["curve"][-1] if info["curve"] else None
    return {
        "name": name,
        "run_dir": str(run_dir),
        "keyframes": info["data"]["keyframes"],
        "scenes": len(info["data"]["scenes"]),
        "steps": info["steps"],
        "init": str(init) if init else None,
        "seed": tcfg.seed,
        "curve": info["curve"],
        "elapsed": info["elapsed"],
        "load_avg": info["load_avg"],
        "eval": {k: results["vector"][k] for k in EVAL_KEYS},
        "eval_seg": {k: results["seg"][k] for k in EVAL_KEYS},
        "bev_seg": results["vector"]["bev_seg"],
        # the in-process curve's last point and the CLI's scores must agree (same functions, same files)
        "eval_matches_curve": last is None
        or (
            abs(last["mAP"] - results["vector"]["mAP"]) < 1e-9
            and abs(last["seg_mAP"] - results["seg"]["mAP"]) < 1e-9
        ),
    }


def table1_jobs(cfg: TransferConfig) -> list[RunJob]:
    """One run per training set and seed (the AV2-rig runs, dearest, first: the pool ends balanced)."""
    order = sorted(cfg.sets, key=lambda name: name != "native")
    return [
        RunJob(f"{name}-s{seed}", name, cfg.steps, seed, cfg.eval_points, tags=(("set", name),))
        for name in order
        for seed in cfg.seeds
    ]


def prior_only(cfg: TransferConfig, out: Path, test: TestSet) -> dict:
    """The oracle models on flat grey test images: how much of their score the map prior alone gives."""
    res = {}
    for seed in cfg.seeds:
        res[f"truth-s{seed}"] = test.curve_point(load_model(out / "runs" / f"truth-s{seed}"), test.blank())
    return res


def table2_jobs(cfg: TransferConfig) -> list[RunJob]:
    """Per fraction of the oracle set and seed: from scratch, and from the nuAV2 run of that seed."""
    return [
        RunJob(
            f"ft{round(frac * 100):g}-{arm}-s{seed}",
            "truth",
            cfg.finetune_steps,
            seed,
            2,
            fraction=frac,
            init=f"{cfg.pretrain_set}-s{seed}" if arm == "pretrained" else None,
            tags=(("fraction", frac), ("arm", arm)),
        )
        for frac in cfg.fractions
        for seed in cfg.seeds
        for arm in ("scratch", "pretrained")
    ]


def run_transfer(
    cfg: TransferConfig,
    out: str | Path,
    *,
    command: str = "",
    progress: bool | None = None,
    figures: bool = True,
) -> dict:
    """The whole benchmark under ``out``; returns (and writes ``transfer.json``) the result."""
    from nuav2.bench.transfer_report import summarize, write_figures, write_markdown

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    progress = True if progress is None else progress
    t0, c0, load0 = time.perf_counter(), time.process_time(), list(os.getloadavg())
    torch.set_num_threads(cfg.threads)
    data_info = prepare_data(cfg, out, progress)
    t_data = time.perf_counter() - t0
    test = TestSet(cfg, out)
    for name in cfg.sets:  # fill the tensor cache here, once, before workers read it
        train_tensors(cfg, out, name)
    for frac in cfg.fractions:
        train_tensors(cfg, out, "truth", frac)
    t1_jobs, t2_jobs = table1_jobs(cfg), table2_jobs(cfg)
    runs = run_jobs(cfg, out, t1_jobs + t2_jobs, test)
    table1 = {j.key: runs[j.key] for j in t1_jobs}
    table2 = {j.key: runs[j.key] for j in t2_jobs}
    result = {
        "benchmark": "transfer",
        "command": command,
        "config": cfg.to_dict(),
        "output": str(out),
        "test_set": {
            "dataroot": str(test.dataroot),
            "version": cfg.version,
            "split": test.split,
            "keyframes": len(test.data),
            "scenes": test.data.meta["scenes"],
        },
        **data_info,
        "runs": {**table1, **table2},
        "prior_only": prior_only(cfg, out, test),
        "timing": {
            "wall_s": time.perf_counter() - t0,
            "cpu_s_main_process": time.process_time() - c0,
            "data_wall_s": t_data,
            "load_avg_start": load0,
            "load_avg_end": list(os.getloadavg()),
        },
    }
    result.update(summarize(result))
    result["seg_decoded"] = summarize(result, "eval_seg")
    if figures:
        result["figures"] = write_figures(result, out, test)
    atomic_write_json(out / RESULT_FILE, result, indent=1)
    write_markdown(result, out / "transfer.md")
    return result
