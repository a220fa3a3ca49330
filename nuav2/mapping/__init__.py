"""A small camera-only online-mapping model (MapTRv2 in miniature) that trains on a CPU.

    from nuav2.mapping import MapModelConfig, TrainConfig, load_map_tensors, train, predict

    data = load_map_tensors(dataroot, "v1.0-nuav2", "av2_train", MapModelConfig())
    info = train(MapModelConfig(), TrainConfig(steps=3000), data, "runs/oracle")
    preds = predict(load_model("runs/oracle"), load_map_tensors(test_root, version, split, cfg))

Data comes only through :mod:`nuav2.maptr` datasets; predictions are MapTR result files, scored
by ``nuav2 eval``. ``nuav2 bench transfer`` uses it to rerun the MapGS paper's Table 1 and 2.
"""

from nuav2.mapping.config import LossConfig, MapModelConfig, TrainConfig
from nuav2.mapping.data import MapTensors, load_map_tensors
from nuav2.mapping.model import MapModel
from nuav2.mapping.predict import (
    bev_seg_scores,
    predict,
    predict_from_seg,
    score_in_process,
    score_with_nuav2_eval,
    write_results,
)
from nuav2.mapping.train import load_model, train

__all__ = [
    "LossConfig",
    "bev_seg_scores",
    "MapModel",
    "MapModelConfig",
    "MapTensors",
    "TrainConfig",
    "load_map_tensors",
    "load_model",
    "predict",
    "predict_from_seg",
    "score_in_process",
    "score_with_nuav2_eval",
    "train",
    "write_results",
]
