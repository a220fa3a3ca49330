"""``nuav2 infos --workers N``: the same .pkl bytes as one process, and the records MapTR expects."""

from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np
from nuscenes.nuscenes import NuScenes
from test_executor_support import VERSION, infos_files

from nuav2.maptr.infos import annotation_of, sample_info
from nuav2.maptr.subsets import split_sample_tokens
from nuav2.maptr.vectorize import MapGT

pytest_plugins = ["test_executor_support"]  # the reference_out fixture


def _same(a, b) -> bool:
    if isinstance(a, dict):
        return isinstance(b, dict) and list(a) == list(b) and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, list):
        return isinstance(b, list) and len(a) == len(b) and all(map(_same, a, b))
    if isinstance(a, np.ndarray):
        return isinstance(b, np.ndarray) and a.dtype == b.dtype and np.array_equal(a, b)
    return type(a) is type(b) and a == b


def test_parallel_infos_are_byte_identical_and_hold_each_keyframe_record(reference_out: Path, tmp_path: Path):
    one = infos_files(reference_out, tmp_path / "one")
    two = infos_files(reference_out, tmp_path / "two", "--workers", "2")
    assert sorted(one) == ["nuav2_map_infos_temporal_all.pkl", "nuav2_map_infos_temporal_av2_train.pkl"]
    assert two == one

    # The streamed file is one plain pickle of {"infos": [...], "metadata": {...}}, record for record
    # what sample_info + the map GT give for each keyframe of the split, scene by scene.
    data = pickle.loads(one["nuav2_map_infos_temporal_all.pkl"])
    assert list(data) == ["infos", "metadata"] and data["metadata"] == {"version": VERSION}
    nusc = NuScenes(VERSION, str(reference_out), verbose=False)
    gt = MapGT(reference_out)
    tokens = split_sample_tokens(nusc, "all")
    assert [info["token"] for info in data["infos"]] == tokens and len(tokens) == 15
    for info in data["infos"]:
        frame_idx = info["frame_idx"]
        expected = sample_info(nusc, info["token"], frame_idx)
        expected["annotation"] = annotation_of(gt.sample_vectors(nusc, info["token"]))
        assert _same(info, expected), info["token"]
    assert any(len(v) for info in data["infos"] for v in info["annotation"].values())  # the GT is not empty
