"""The devkit's tracking evaluation (``TrackingEval``) on what ``nuav2 convert`` writes.

The ground truth submitted as a tracking result must score perfectly (AMOTA 1, no identity switches);
the same submission with two tracks' identities swapped half-way must not, so the check can fail.
TrackingEval needs ``motmetrics`` (the devkit does not declare it; nuav2's dev extra pins 1.4.0).
"""

from __future__ import annotations

import json
from pathlib import Path

import matplotlib
import pytest
from e2e_helpers import VERSION

matplotlib.use("Agg")
pytest_plugins = ["test_writer_support", "e2e_support"]

SPLIT = "av2_train"  # e2e_support's synthetic log is a train log


def gt_submission(nusc, swap_after: int | None = None) -> tuple[dict, int]:
    """Every annotation as a tracking box with its instance as the track id (velocity from the devkit).
    ``swap_after``: from that sample on, the first two tracked instances trade ids. Returns (results,
    number of tracked boxes)."""
    import numpy as np
    from nuscenes.eval.tracking.utils import category_to_tracking_name

    results, n, swapped = {}, 0, {}
    for i, sample in enumerate(sorted(nusc.sample, key=lambda s: s["timestamp"])):
        boxes = []
        for tok in sample["anns"]:
            ann = nusc.get("sample_annotation", tok)
            name = category_to_tracking_name(ann["category_name"])
            if name is None:
                continue
            if swap_after is not None and len(swapped) < 2 and ann["instance_token"] not in swapped \
                    and name == "car":
                swapped[ann["instance_token"]] = None
            track = ann["instance_token"]
            if swap_after is not None and i >= swap_after and len(swapped) == 2 and track in swapped:
                a, b = list(swapped)
                track = b if track == a else a
            boxes.append({"sample_token": sample["token"], "translation": ann["translation"],
                          "size": ann["size"], "rotation": ann["rotation"],
                          "velocity": np.nan_to_num(nusc.box_velocity(tok)[:2]).tolist(),
                          "tracking_id": track, "tracking_name": name, "tracking_score": 0.9})
        results[sample["token"]] = boxes
        n += len(boxes)
    return results, n


def evaluate(db: Path, results: dict, out: Path) -> dict:
    from nuscenes.eval.common.config import config_factory
    from nuscenes.eval.tracking.evaluate import TrackingEval

    out.mkdir(parents=True, exist_ok=True)
    meta = {"use_camera": False, "use_lidar": True, "use_radar": False, "use_map": False,
            "use_external": False}
    (out / "sub.json").write_text(json.dumps({"meta": meta, "results": results}))
    ev = TrackingEval(config_factory("tracking_nips_2019"), str(out / "sub.json"), eval_set=SPLIT,
                      output_dir=str(out), nusc_version=VERSION, nusc_dataroot=str(db), verbose=False)
    return ev.main(render_curves=False)


@pytest.mark.parametrize("db_fixture", ["native_synth_db", "warp_db"])
def test_ground_truth_tracks_score_perfectly_and_swapped_ones_do_not(db_fixture: str, request, tmp_path):
    from nuscenes import NuScenes

    db = request.getfixturevalue(db_fixture)
    nusc = NuScenes(VERSION, str(db), verbose=False)
    results, n = gt_submission(nusc)
    assert n > 20
    metrics = evaluate(db, results, tmp_path / "gt")
    assert metrics["amota"] == pytest.approx(1.0)
    assert metrics["ids"] == 0 and metrics["frag"] == 0
    assert metrics["amotp"] < 1e-3  # metres: the boxes are the GT's own

    swapped, _ = gt_submission(nusc, swap_after=len(nusc.sample) // 2)
    metrics = evaluate(db, swapped, tmp_path / "swapped")
    assert metrics["ids"] >= 2
