"""The vector decoder's refinement: a layer must be able to move each of a query's points to its own
target, so it has to know which point is which, not only where each point is."""

from __future__ import annotations

import importlib

import torch

from nuav2.mapping.config import MapModelConfig
from nuav2.mapping.head import DecoderLayer


def test_a_layer_moves_coinciding_points_of_one_query_apart():
    """Found by review: overfitting one scene, the last layer's points came out of order along the line
    (centerline AP 1.0 from layer 0, 0.71 from layer 2): a point's offset depended only on its position
    and its query, so points at one place always moved together. MapTR gives each point its own query."""
    torch.manual_seed(0)
    cfg = MapModelConfig()
    channels = 8
    layer = DecoderLayer(cfg, channels).eval()
    torch.nn.init.normal_(layer.offset[-1].weight, std=0.1)  # zero at init (no refinement yet)
    rows, cols = cfg.bev_shape
    bev = torch.randn(1, channels, rows, cols)
    memory = torch.randn(1, 12, cfg.decoder_dim)
    q = torch.randn(1, 2, cfg.decoder_dim)
    pts = torch.full((1, 2, cfg.num_points, 2), 0.5)  # every point of both queries at the patch centre
    with torch.no_grad():
        _, new_pts, _ = layer(q, pts, bev, memory)
    spread = new_pts[0].std(dim=1).norm(dim=-1)  # per query: how far its points now lie apart
    assert torch.isfinite(new_pts).all() and bool((spread > 1e-3).all()), spread


def test_weights_of_the_layout_before_the_point_embedding_are_refused_by_name(tmp_path):
    """Found by review: a run saved before the embedding was reused by train() as done (its fingerprint
    named no architecture) and load_model failed with torch's 'Missing key(s)' list."""
    import dataclasses
    import json

    import pytest

    train_mod = importlib.import_module("nuav2.mapping.train")  # nuav2.mapping.train is also a function
    from nuav2.mapping.model import MapModel

    cfg = MapModelConfig()
    old = {k: v for k, v in MapModel(cfg).state_dict().items() if "point_embed" not in k}
    run = tmp_path / "run"
    run.mkdir()
    torch.save(old, run / train_mod.MODEL)
    (run / train_mod.RUN_JSON).write_text(json.dumps({"model_config": dataclasses.asdict(cfg)}))
    layers = MapModelConfig().decoder_layers
    named = rf"retrain \({layers} missing \(e\.g\. decoder\.layers\.0\.point_embed\)\)"
    with pytest.raises(ValueError, match=r"model\.pt: weights of another model layout .* " + named):
        train_mod.load_model(run)


def test_the_run_fingerprint_names_the_architecture(monkeypatch):
    train_mod = importlib.import_module("nuav2.mapping.train")  # nuav2.mapping.train is also a function
    from nuav2.mapping.config import TrainConfig

    class Data:
        meta = {"keyframes": 3}

        def __len__(self):
            return 3

    now = train_mod.run_fingerprint(MapModelConfig(), TrainConfig(), Data(), None)
    monkeypatch.setattr(train_mod, "ARCHITECTURE", train_mod.ARCHITECTURE - 1)
    assert train_mod.run_fingerprint(MapModelConfig(), TrainConfig(), Data(), None) != now
