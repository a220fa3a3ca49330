"""The mapping model on what ``nuav2 convert`` really writes: data through ``nuav2.maptr``, a short
training run that lowers its loss, a killed run that resumes to the same weights, and predictions
that ``nuav2 eval`` scores exactly as the in-process evaluator does."""

from __future__ import annotations

import json

import pytest
import torch
from transfer_dbs import synthetic_truth_db

from nuav2.mapping import (
    MapModelConfig,
    TrainConfig,
    bev_seg_scores,
    load_map_tensors,
    load_model,
    predict,
    score_in_process,
    score_with_nuav2_eval,
    train,
    write_results,
)
from nuav2.maptr.vectorize import gt_vectors_for_split

SMALL = MapModelConfig(
    input_focal_px=60.0,
    stem_channels=8,
    stage_channels=(16, 32, 48),
    feat_channels=24,
    depth_bins=16,
    bev_cell_m=1.0,
    bev_channels=24,
    num_queries=16,
    one2many_queries=16,
    decoder_layers=2,
    decoder_dim=32,
    decoder_heads=2,
)
VERSION, SPLIT = "v1.0-nuav2", "av2_train"


@pytest.fixture(scope="module")
def truth_db(tmp_path_factory):
    return synthetic_truth_db(tmp_path_factory.mktemp("mapdb"), seed=5, seconds=0.4, scale=0.08)[1]


def test_tensors_come_from_the_maptr_dataset_at_the_model_focal_length(truth_db, tmp_path):
    from nuav2.maptr.dataset import MapSampleDataset

    data = load_map_tensors(truth_db, VERSION, SPLIT, SMALL, cache_dir=tmp_path)
    ds = MapSampleDataset(truth_db, VERSION, SPLIT, image_scale=data.meta["image_scale"])
    assert len(data) == len(ds) == 4
    item = ds[2]
    assert data.tokens[2] == item["sample_token"]
    fx = item["cam_intrinsic"][:, 0, 0]
    assert torch.allclose(fx.median(), torch.tensor(SMALL.input_focal_px), rtol=1e-5)
    h, w = item["img"].shape[-2:]
    assert torch.equal(data.img[2, :, :, :h, :w], item["img"])
    assert torch.equal(data.gt_labels[2], item["gt_labels"])
    torch.testing.assert_close(data.lidar2img[2], item["lidar2img"])
    assert data.bev_target[2].sum() > 0 and data.pv_target[2].sum() > 0
    again = load_map_tensors(truth_db, VERSION, SPLIT, SMALL, cache_dir=tmp_path)  # from the cache file
    assert len(list(tmp_path.glob("maptensors-*.pt"))) == 1
    assert torch.equal(again.img, data.img) and again.tokens == data.tokens


def test_training_lowers_the_loss(truth_db, tmp_path):
    data = load_map_tensors(truth_db, VERSION, SPLIT, SMALL)
    info = train(
        SMALL,
        TrainConfig(steps=40, batch_size=2, lr=3e-3, warmup_steps=5, eval_every=0),
        data,
        tmp_path / "run",
        progress=False,
    )
    totals = [x["total"] for x in info["losses"]]
    assert len(totals) == 40
    assert sum(totals[-5:]) / 5 < 0.8 * sum(totals[:3]) / 3


class _Stop(Exception):
    pass


def test_a_killed_run_resumes_to_the_same_weights(truth_db, tmp_path):
    data = load_map_tensors(truth_db, VERSION, SPLIT, SMALL)
    cfg = TrainConfig(steps=6, batch_size=2, warmup_steps=2, eval_every=3, checkpoint_every=2)
    whole = train(SMALL, cfg, data, tmp_path / "whole", evaluator=lambda m: {"mAP": 0.0}, progress=False)

    def killer(model):
        raise _Stop

    with pytest.raises(_Stop):  # killed at step 3, after the step-2 checkpoint
        train(SMALL, cfg, data, tmp_path / "killed", evaluator=killer, progress=False)
    assert not (tmp_path / "killed" / "run.json").exists()
    resumed = train(SMALL, cfg, data, tmp_path / "killed", evaluator=lambda m: {"mAP": 0.0}, progress=False)
    assert resumed["steps"] == whole["steps"] == 6
    a, b = load_model(tmp_path / "whole").state_dict(), load_model(tmp_path / "killed").state_dict()
    for k in a:
        torch.testing.assert_close(a[k], b[k], rtol=1e-5, atol=1e-6, msg=k)
    # a finished run is reused, not retrained
    mtime = (tmp_path / "whole" / "model.pt").stat().st_mtime_ns
    again = train(SMALL, cfg, data, tmp_path / "whole", progress=False)
    assert again["fingerprint"] == whole["fingerprint"]
    assert (tmp_path / "whole" / "model.pt").stat().st_mtime_ns == mtime


def test_predictions_are_scored_by_nuav2_eval_as_in_process(truth_db, tmp_path):
    data = load_map_tensors(truth_db, VERSION, SPLIT, SMALL)
    train(SMALL, TrainConfig(steps=2, batch_size=1, eval_every=0), data, tmp_path / "run", progress=False)
    preds = predict(load_model(tmp_path / "run"), data)
    assert set(preds) == set(data.tokens) and all(len(v) == 50 for v in preds.values())
    gts = gt_vectors_for_split(truth_db, VERSION, SPLIT)
    # add GT-like vectors (0.3 m off) on half the samples so the scores are far from 0
    for tok in data.tokens[::2]:
        preds[tok] += [(c, p + 0.3, 0.9) for c, p in gts[tok]]
    path = write_results(tmp_path / "pred.json", preds, SMALL.classes)
    rec = json.loads(path.read_text())["results"][0]["vectors"][0]
    assert set(rec) == {"pts", "pts_num", "cls_name", "type", "confidence_level"} and rec["pts_num"] == 20
    cli = score_with_nuav2_eval(path, truth_db, VERSION, SPLIT, SMALL.classes, tmp_path / "eval.json")
    here = score_in_process(preds, gts, SMALL.classes)
    assert cli["n_samples"] == len(data)
    assert 0.2 < here["mAP"] < 1.0
    assert cli["mAP"] == pytest.approx(here["mAP"], abs=1e-6)
    for c in SMALL.classes:
        assert cli["ap"][c] == pytest.approx(here["ap"][c], abs=1e-6)


def test_nuav2_eval_cuts_the_gt_at_the_model_s_patch(truth_db, tmp_path):
    """The model's own GT, exported as predictions, scores 1.0 through nuav2 eval at a patch other
    than the default (the GT used to be cut at 60 x 30 m whatever the model's patch)."""
    patch = (40.0, 20.0)
    gts = gt_vectors_for_split(truth_db, VERSION, SPLIT, patch=patch)
    preds = {tok: [(c, p, 0.9) for c, p in vecs] for tok, vecs in gts.items()}
    path = write_results(tmp_path / "pred.json", preds, SMALL.classes)
    present = [c for c in SMALL.classes if any(c == v[0] for vecs in gts.values() for v in vecs)]
    cli = score_with_nuav2_eval(path, truth_db, VERSION, SPLIT, present, tmp_path / "eval.json", patch=patch)
    assert cli["mAP"] == pytest.approx(1.0)


def test_one_to_many_queries_train_only_and_never_see_the_others():
    from nuav2.mapping import MapModel

    cfg = MapModelConfig(**{**SMALL.__dict__, "one2many_queries": 8})  # not SMALL's 16: any count works
    model = MapModel(cfg).eval()
    img = torch.randint(0, 255, (1, 2, 3, 32, 48), dtype=torch.uint8)
    l2i = torch.eye(4).expand(1, 2, 4, 4).clone()
    hw = torch.tensor([[[32, 48], [32, 48]]])
    plain = model(img, l2i, hw)["layers"]
    both = model(img, l2i, hw, one2many=True)["layers"]
    assert plain[-1][0].shape[1] == cfg.num_queries and both[-1][0].shape[1] == cfg.num_queries + 8
    # the one-to-one queries give the same output whether the training-only group runs or not
    for (c1, p1), (c2, p2) in zip(plain, both):
        torch.testing.assert_close(c1, c2[:, : cfg.num_queries], rtol=1e-5, atol=1e-5)
        torch.testing.assert_close(p1, p2[:, : cfg.num_queries], rtol=1e-5, atol=1e-5)


class _Replay(torch.nn.Module):
    """Stands in for the model: hands back the given BEV logits batch by batch."""

    def __init__(self, logits: torch.Tensor, batch_size: int) -> None:
        super().__init__()
        self.batches = list(logits.split(batch_size))

    def forward(self, img, lidar2img, img_hw):
        return {"bev_seg": self.batches.pop(0)}


def test_bev_seg_scores_of_perfect_inverted_and_shifted_maps(truth_db):
    data = load_map_tensors(truth_db, VERSION, SPLIT, SMALL)
    target = data.bev_target.float()
    perfect = bev_seg_scores(_Replay(20 * target - 10, 4), data)
    assert perfect["ap"] == pytest.approx(1.0) and perfect["f1"] == pytest.approx(1.0)
    assert 0 < perfect["positive_share"] < 0.5
    inverted = bev_seg_scores(_Replay(10 - 20 * target, 4), data)
    assert inverted["ap"] < 2 * inverted["positive_share"] and inverted["f1"] < 0.5
    # lines one cell off still count for F1 (tolerance); moved further, only cells along the shift do
    near = bev_seg_scores(_Replay((20 * target - 10).roll(1, dims=-1), 4), data)
    far = bev_seg_scores(_Replay((20 * target - 10).roll((3, 3), dims=(-2, -1)), 4), data)
    assert near["f1"] > 0.9 > far["f1"]


def test_rotated_frames_carry_the_map_of_the_rotated_patch(truth_db):
    """Angle 0 gives exactly the dataset's own GT; at 15 degrees the GT is the original map rotated
    (checked point by point against the dataset's own polylines), and the rotated ``lidar2img`` sends
    each rotated point to the pixel the original point had."""
    import numpy as np
    from shapely.geometry import MultiLineString, Point

    from nuav2.mapping.rotations import rotate_batch, rotated_targets, rotation_T
    from nuav2.maptr.dataset import MapSampleDataset

    data = load_map_tensors(truth_db, VERSION, SPLIT, SMALL, rotations_deg=(15.0,))
    assert data.meta["rotations_deg"] == [15.0] and len(data.rotated) == len(data)
    ds = MapSampleDataset(truth_db, VERSION, SPLIT, load_images=False)
    same = rotated_targets(ds, 1, 0.0, SMALL)
    assert torch.equal(same["labels"], data.gt_labels[1]) and torch.equal(same["shifts"], data.gt_shifts[1])
    assert torch.equal(same["bev"], data.bev_target[1])

    rot = data.rotated[1][0]
    R = rotation_T(15.0)[:2, :2]
    # the rotated frame's dividers and boundaries lie on the original ones (as the dataset cuts them)
    # rotated, wherever they fall inside the original patch (crossings gain edges along the rotated
    # patch's border and centerlines are simplified after the cut, so those differ legitimately)
    lines = [0, 2]  # divider, boundary
    original = MultiLineString([p @ R.T for c, p in ds[1]["gt_vectors"] if SMALL.classes.index(c) in lines])
    keep = (rot["labels"][:, None] == torch.tensor(lines)).any(1)
    pts = rot["shifts"][keep, 0].reshape(-1, 2).double().numpy()
    back = pts @ R  # into the original frame
    hx, hy = SMALL.half_extent_xy
    inside = (np.abs(back[:, 0]) < hx - 1) & (np.abs(back[:, 1]) < hy - 1)
    assert inside.sum() > 20
    assert max(original.distance(Point(p)) for p in pts[inside]) < 0.01
    assert not torch.equal(rot["bev"], data.bev_target[1])

    batch = rotate_batch(data.batch([1]), [rot], [15.0])
    assert torch.equal(batch["gt_shifts"][0], rot["shifts"])
    p = torch.tensor([[4.0, 9.0, -1.8, 1.0]], dtype=torch.float64)
    q = p.clone()
    q[0, :2] = torch.from_numpy(R @ p[0, :2].numpy())
    a = p @ data.lidar2img[1].double().transpose(-1, -2)
    b = q @ batch["lidar2img"][0].double().transpose(-1, -2)
    torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-3)
