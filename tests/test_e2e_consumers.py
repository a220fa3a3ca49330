"""Every consumer on the real output of ``nuav2 convert``, in every mode (issue 10).

Databases (built once per session in ``e2e_support``): native on the real AV2 fixture, warp,
render and truth on synthetic logs, and two logs converted by two runs into one OUT. Consumers:
``nuav2 split``, ``infos``, ``eval`` (default options and a 3-class result file), ``viz``,
``validate``, the devkit's ``NuScenes`` tutorial calls and ``NuScenesMap.render_map_in_image``.
"""

from __future__ import annotations

import json
import pickle
from pathlib import Path

import matplotlib
import numpy as np
import pytest
from e2e_helpers import VERSION, cli, logs_meta

matplotlib.use("Agg")
pytest_plugins = ["test_writer_support", "e2e_support"]

MODES = ["native", "warp", "render", "truth", "two_runs"]


@pytest.fixture(scope="module", params=MODES)
def db(request) -> Path:
    name = {"native": "native_fixture_db", "warp": "warp_db", "render": "render_db", "truth": "truth_db",
            "two_runs": "two_run_db"}
    value = request.getfixturevalue(name[request.param])
    return value[0] if isinstance(value, tuple) else value


@pytest.fixture(scope="module")
def nusc(db: Path):
    from nuscenes.nuscenes import NuScenes

    return NuScenes(VERSION, str(db), verbose=False)


def _splits(db: Path) -> dict[str, list[str]]:
    return json.loads((db / VERSION / "splits.json").read_text())


def default_eval_split(db: Path) -> str:
    """What ``nuav2 eval`` must pick without --split: the first non-empty of these (docs/evaluation.md)."""
    splits = _splits(db)
    return next(s for s in ("geo_val", "av2_val", "val", "mini_val", "all") if splits.get(s))


def _results_file(path: Path, gts: dict, classes: tuple[str, ...] | None = None) -> Path:
    """A MapTR result file predicting exactly the GT (of ``classes`` only, if given)."""
    results = [{"sample_token": tok, "vectors": [
        {"pts": np.asarray(p).tolist(), "pts_num": len(p), "cls_name": c, "confidence_level": 0.9}
        for c, p in vecs if classes is None or c in classes]} for tok, vecs in gts.items()]
    path.write_text(json.dumps({"meta": {"use_camera": True}, "results": results}))
    return path


def test_split_reads_the_converted_database(db: Path, nusc, caplog):
    code, out, err = cli("split", db, "--version", VERSION, "--min-distance", "20")
    assert code == 0, err
    report = json.loads(out)
    new = report["new"]
    assert sum(new["scenes"].values()) == len(nusc.scene)
    assert sum(new["samples"].values()) == len(nusc.sample)
    written = _splits(db)
    assert {"geo_train", "geo_val", "geo_test", "geo_discarded"} <= set(written)
    assert "av2_train" in written or "av2_val" in written  # the converter's own keys are kept
    if not new["scenes"]["val"] or not new["scenes"]["test"]:
        assert "no scene in" in caplog.text  # few logs: said, not silent
    # Positions are in true city coordinates: the AV2 city frame, not the shifted global one.
    from nuav2.splits import read_scene_table

    placed = read_scene_table(db, VERSION)
    for rec in logs_meta(db):
        scene = placed.positions[rec["scene_name"]]
        assert placed.city_of[rec["scene_name"]] == rec["city"]
        assert np.all(scene > np.asarray(rec["city_offset"][:2]))


def test_infos_export_every_split(db: Path, nusc, tmp_path: Path):
    code, out, err = cli("infos", db, "--version", VERSION, "--out", tmp_path)
    assert code == 0, err
    written = json.loads(out)
    assert set(written) == set(_splits(db))
    with open(written["all"], "rb") as f:
        infos = pickle.load(f)["infos"]
    assert sorted(i["token"] for i in infos) == sorted(s["token"] for s in nusc.sample)
    assert all(i["cams"] and np.isfinite(i["ego2global_translation"]).all() for i in infos)
    assert any(len(v) for i in infos for v in i["annotation"].values())  # map GT vectors exist
    assert "PYTHONPATH=" in err and "devkit_hook" in err  # how MapTR's own stack opens the maps


def test_eval_with_default_options(db: Path, tmp_path: Path):
    from nuav2.maptr.vectorize import gt_vectors_for_split

    split = default_eval_split(db)
    gts = gt_vectors_for_split(db, VERSION, split)
    pred = _results_file(tmp_path / "results.json", gts)
    code, out, err = cli("eval", pred, "--dataroot", db, "--version", VERSION, "--json")
    assert code == 0, err
    result = json.loads(out)
    assert result["gt_source"].endswith(f"split {split} (from the map)")
    with_gt = [c for c in result["classes"] if result["num_gts"][c]]
    assert with_gt and result["mAP"] == pytest.approx(1.0, abs=1e-9)
    assert "\r" not in err  # no progress-bar redraws when stderr is not a terminal


def test_eval_scores_a_three_class_result_file_on_its_classes(db: Path, tmp_path: Path):
    """MapTRv2 without centerlines: the missing class is left out of the mAP, not averaged in as 0."""
    from nuav2.maptr.vectorize import gt_vectors_for_split

    split = default_eval_split(db)
    gts = gt_vectors_for_split(db, VERSION, split)
    three = ("divider", "ped_crossing", "boundary")
    present = [c for c in three if any(c == v[0] for vecs in gts.values() for v in vecs)]
    assert any(v[0] == "centerline" for vecs in gts.values() for v in vecs)
    pred = _results_file(tmp_path / "results3.json", gts, three)
    code, out, err = cli("eval", pred, "--dataroot", db, "--version", VERSION, "--split", split)
    assert code == 0, err
    assert f"mAP (headline) over {len(present)} classes ({', '.join(present)}): 1.0000" in out
    assert "left out (no prediction in the result file): centerline" in out
    code, out, err = cli("eval", pred, "--dataroot", db, "--version", VERSION, "--split", split, "--json",
                         "--classes", *three, "centerline")
    assert code == 0 and json.loads(out)["mAP"] == pytest.approx(len(present) / 4)  # asked for: AP 0


def test_eval_scores_a_class_the_model_lost_as_zero(db: Path, tmp_path: Path, caplog):
    """A 4-class model whose file lost ped_crossing: MapTR averages its configured classes, so the lost
    class scores AP 0 (leaving it out would score the model higher than MapTR does)."""
    from nuav2.maptr.vectorize import gt_vectors_for_split

    split = default_eval_split(db)
    gts = gt_vectors_for_split(db, VERSION, split)
    kept = ("divider", "boundary", "centerline")
    pred = _results_file(tmp_path / "lost_ped.json", gts, kept)
    code, out, err = cli("eval", pred, "--dataroot", db, "--version", VERSION, "--split", split, "--json")
    assert code == 0, err
    result = json.loads(out)
    assert result["classes"] == ["divider", "ped_crossing", "boundary", "centerline"]
    assert result["classes_left_out"] == []
    assert any("ped_crossing" in r.getMessage() and "AP 0" in r.getMessage() for r in caplog.records)
    assert result["class_mean_ap"]["ped_crossing"] == 0.0
    present = [c for c in kept if result["num_gts"][c]]
    assert result["mAP"] == pytest.approx(len(present) / 4)


def test_viz_draws_a_converted_sample(db: Path, nusc, tmp_path: Path):
    import cv2

    token = nusc.sample[len(nusc.sample) // 2]["token"]
    png = tmp_path / "viz.png"
    code, out, err = cli("viz", db, "--version", VERSION, "--sample", token, "--out", png,
                         "--tile-height", "90")
    assert code == 0, err
    img = cv2.imread(str(png))
    assert img is not None and img.shape[0] >= 90 and img.std() > 1


def test_validate_passes_with_devkit_and_decoded_images(db: Path):
    code, out, err = cli("validate", db, "--version", VERSION, "--devkit", "--decode-images", "--quiet")
    assert code == 0, out + err
    assert out.startswith("OK:")


def test_devkit_tutorial_calls(db: Path, nusc, tmp_path: Path):
    import matplotlib.pyplot as plt

    nusc.list_categories()
    nusc.list_scenes()
    sample = nusc.sample[0]
    nusc.list_sample(sample["token"])
    cams = [ch for ch in sample["data"] if ch != "LIDAR_TOP"]
    nusc.render_sample_data(sample["data"]["LIDAR_TOP"], nsweeps=2, out_path=str(tmp_path / "lidar.png"),
                            verbose=False)
    nusc.render_sample_data(sample["data"][cams[0]], out_path=str(tmp_path / "cam.png"), verbose=False)
    nusc.render_pointcloud_in_image(sample["token"], camera_channel=cams[0],
                                    out_path=str(tmp_path / "pc.png"), verbose=False)
    # render_annotation looks for channels named *CAM* (the nuScenes rig; native mode keeps AV2's names).
    seen = [b.token for ch in cams if "CAM" in ch for b in nusc.get_sample_data(sample["data"][ch])[1]]
    if seen:
        nusc.render_annotation(seen[0], out_path=str(tmp_path / "ann.png"))
        assert (tmp_path / "ann.png").stat().st_size > 1000
    plt.close("all")
    for name in ("lidar", "cam", "pc"):
        assert (tmp_path / f"{name}.png").stat().st_size > 1000
    # Sweeps aggregate in the rigid global frame: LidarPointCloud.from_file_multisweep.
    from nuscenes.utils.data_classes import LidarPointCloud

    pc, times = LidarPointCloud.from_file_multisweep(nusc, sample, "LIDAR_TOP", "LIDAR_TOP", nsweeps=3)
    assert pc.points.shape[1] > 1000 and np.isfinite(pc.points).all()


def test_ego_sits_near_global_z_zero(db: Path, nusc):
    """The global frame is the city frame minus (x, y, ground z under the first pose): ego z ~ 0."""
    z = np.array([p["translation"][2] for p in nusc.ego_pose])
    assert np.abs(z).max() < 0.5
    for rec in logs_meta(db):
        assert len(rec["city_offset"]) == 3 and rec["city_offset"][2] != 0.0


def test_render_map_in_image_draws_patches(db: Path, nusc):
    import matplotlib.pyplot as plt
    from nuscenes.map_expansion.map_api import NuScenesMap

    drawn = 0
    for log in nusc.log:
        nmap = NuScenesMap(str(db), map_name=log["location"])
        scene = next(s for s in nusc.scene if s["log_token"] == log["token"])
        sample = nusc.get("sample", scene["first_sample_token"])
        for ch in (c for c in sample["data"] if c != "LIDAR_TOP"):
            _, ax = nmap.render_map_in_image(nusc, sample["token"], camera_channel=ch, min_polygon_area=0,
                                             verbose=False)
            drawn += len(ax.patches)
            plt.close("all")
        assert drawn > 0, log["location"]


def test_prediction_rasterizer_draws_the_agents_map(db: Path, nusc):
    """nuscenes.prediction's StaticLayerRasterizer loads its maps by the four nuScenes names; the
    hook opens the log table's nuAV2 locations instead, so the stock input representation works."""
    from nuscenes.prediction import PredictHelper
    from nuscenes.prediction.input_representation.agents import AgentBoxesWithFadedHistory
    from nuscenes.prediction.input_representation.combinators import Rasterizer
    from nuscenes.prediction.input_representation.interface import InputRepresentation
    from nuscenes.prediction.input_representation.static_layers import StaticLayerRasterizer

    helper = PredictHelper(nusc)
    static = StaticLayerRasterizer(helper)
    cars = [a for a in nusc.sample_annotation if a["category_name"].startswith("vehicle.car")]
    assert cars
    ann = cars[len(cars) // 2]
    agents = AgentBoxesWithFadedHistory(helper, seconds_of_history=1)
    image = InputRepresentation(static, agents, Rasterizer()).make_input_representation(
        ann["instance_token"], ann["sample_token"])
    assert image.shape == (500, 500, 3)
    layers = static.make_representation(ann["instance_token"], ann["sample_token"])
    drivable = np.all(layers == 255, axis=2).mean()  # drivable_area is drawn white
    assert 0.05 < drivable < 0.95
    assert len(static.maps.names) == len(nusc.log) and set(static.maps) <= set(static.maps.names)


def test_prediction_off_road_rate_reads_the_drivable_area(db: Path, nusc):
    """The devkit's OffRoadRate renders every location's drivable mask when built, from load_all_maps's
    items(): the lazy nuAV2 mapping listed none, and every prediction raised KeyError on its location.
    Now a mask is made when a prediction first needs it: a car's own track scores 0, 1 km off scores 1."""
    from nuscenes.eval.prediction.data_classes import Prediction
    from nuscenes.eval.prediction.metrics import OffRoadRate, RowMean
    from nuscenes.prediction import PredictHelper

    helper = PredictHelper(nusc)
    metric = OffRoadRate(helper, [RowMean()])
    masks = metric.drivable_area_polygons
    assert dict.__len__(masks) == 0 and sorted(masks) == sorted({log["location"] for log in nusc.log})
    scored = 0
    for ann in nusc.sample_annotation:
        if not ann["category_name"].startswith("vehicle.car") or not ann["prev"] or not ann["next"]:
            continue
        track = helper.get_past_for_agent(ann["instance_token"], ann["sample_token"], 1.0, False)
        if len(track) < 2 or ann["num_lidar_pts"] < 20:
            continue
        modes = np.stack([track, track + 1000.0])
        prediction = Prediction(ann["instance_token"], ann["sample_token"], modes, np.array([0.5, 0.5]))
        assert metric(None, prediction)[0] == pytest.approx(0.5)  # on the road; the copy is off the map
        scored += 1
    if not scored:
        pytest.skip("no car with a second of history (the real fixture ships one sweep)")
    assert dict.__len__(masks) >= 1


def test_prediction_helper_past_and_future_cover_the_seconds_asked(db: Path, nusc):
    """The devkit caps a past / future at 2 annotations a second (nuScenes' keyframe rate); nuAV2 keys
    every 10 Hz sweep by default, where ``seconds=0.3`` returned nothing (int(2 x 0.3) = 0) and
    ``seconds=1`` 0.2 s of history before the hook."""
    from nuscenes.prediction import PredictHelper

    helper, seconds, checked = PredictHelper(nusc), 0.3, 0
    for ann in nusc.sample_annotation:
        sample = nusc.get("sample", ann["sample_token"])
        scene = nusc.get("scene", sample["scene_token"])
        first, last = (nusc.get("sample", scene[k])["timestamp"]
                       for k in ("first_sample_token", "last_sample_token"))
        if scene["nbr_samples"] < 2:
            continue
        tolerance = min(0.15, 0.5 * (last - first) / 1e6 / (scene["nbr_samples"] - 1))  # half a period
        for direction, get in (("prev", helper.get_past_for_agent), ("next", helper.get_future_for_agent)):
            chain, rec = [], ann
            while rec[direction]:
                rec = nusc.get("sample_annotation", rec[direction])
                t_us = nusc.get("sample", rec["sample_token"])["timestamp"]
                chain.append(abs(t_us - sample["timestamp"]) / 1e6)
            if not chain or chain[-1] < seconds:
                continue  # the track does not last that long this way
            got = get(ann["instance_token"], ann["sample_token"], seconds=seconds, in_agent_frame=False,
                      just_xy=False)
            assert len(got) == sum(dt < seconds + tolerance for dt in chain), direction
            span = abs(nusc.get("sample", got[-1]["sample_token"])["timestamp"] - sample["timestamp"]) / 1e6
            assert seconds - tolerance <= span < seconds + tolerance, (direction, span)
            checked += 1
    if max(s["nbr_samples"] for s in nusc.scene) < 4:
        pytest.skip("no scene has 4 samples (the real fixture ships one sweep): no track spans 0.3 s")
    assert checked > 0


def test_prediction_helper_takes_the_rate_following_walk_from_2_25_hz():
    """2.5 Hz keyframes measure 2.49994 or 2.50008 Hz by their sweeps' timing: both must follow the
    scene's rate (a threshold at 2.5 sent one log to the devkit's 2-a-second cap and one not)."""
    import sys

    import nuav2  # noqa: F401  (loads the hook file as the module nuav2_devkit_locations)

    follows_scene_rate = sys.modules["nuav2_devkit_locations"].follows_scene_rate

    assert not any(follows_scene_rate(r) for r in (None, 1.0, 2.0, 2.00006, 1.99994))
    assert all(follows_scene_rate(r) for r in (2.49994, 2.5, 2.50008, 5.0, 9.99942))
