"""Native conversion of a synthetic AV2 log (images, 20 sweeps, moving actors) against the world's truth."""

from __future__ import annotations

import json
from pathlib import Path

import matplotlib
import numpy as np
import pytest
from nuscenes.nuscenes import NuScenes

from nuav2.convert import ConvertOptions, convert_av2
from nuav2.geometry import quat_to_rot
from nuav2.nuscenes_db.tokens import make_token

matplotlib.use("Agg")
VERSION = "v1.0-nuav2"
RING = ["ring_front_center", "ring_front_left", "ring_front_right", "ring_side_left", "ring_side_right",
        "ring_rear_left", "ring_rear_right"]


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory):
    """(log dir, world, dataroot at --keyframe-hz 2 with copied images)."""
    from nuav2.synth import SynthConfig, generate_log, load_world

    root = tmp_path_factory.mktemp("synthetic_av2")
    log_dir = generate_log(root, seed=3, config=SynthConfig(seconds=2.0))
    out = tmp_path_factory.mktemp("synthetic_db")
    report = convert_av2(log_dir.parent, out, ConvertOptions(keyframe_hz=2.0, show_progress=False))
    assert report.ok, report.failed
    return log_dir, load_world(log_dir), out


@pytest.fixture(scope="module")
def nusc(synthetic) -> NuScenes:
    return NuScenes(VERSION, str(synthetic[2]), verbose=False)


def _global_to_city(db: Path) -> np.ndarray:
    return np.array(json.loads((db / VERSION / "nuav2_logs.json").read_text())[0]["city_offset"])


def test_samples_sweeps_and_links_at_2hz(nusc: NuScenes, synthetic):
    log_dir, world, out = synthetic
    sweeps = world.timeline.sweeps_ns
    assert len(nusc.sample) == 4  # 20 sweeps at 10 Hz, every 5th
    assert [s["timestamp"] for s in nusc.sample] == [int(sweeps[k]) // 1000 for k in (0, 5, 10, 15)]
    for s in nusc.sample:
        assert set(s["data"]) == {"LIDAR_TOP", *RING}
    scene = nusc.scene[0]
    chain, tok = [], scene["first_sample_token"]
    while tok:
        chain.append(tok)
        tok = nusc.get("sample", tok)["next"]
    assert chain == [s["token"] for s in nusc.sample] and chain[-1] == scene["last_sample_token"]
    # Every channel: one prev/next chain through key frames and sweeps in time order.
    by_channel: dict[str, list[dict]] = {}
    for sd in nusc.sample_data:
        by_channel.setdefault(sd["channel"], []).append(sd)
    assert len(by_channel["LIDAR_TOP"]) == 20 and all(len(by_channel[c]) == 40 for c in RING)
    for ch, sds in by_channel.items():
        first = [sd for sd in sds if sd["prev"] == ""]
        assert len(first) == 1, ch
        walk, sd = [], first[0]
        while True:
            walk.append(sd)
            if not sd["next"]:
                break
            sd = nusc.get("sample_data", sd["next"])
        assert len(walk) == len(sds) and all(a["timestamp"] < b["timestamp"] for a, b in zip(walk, walk[1:]))
        for sd in walk:
            sample = nusc.get("sample", sd["sample_token"])
            if sd["is_key_frame"]:
                assert sample["data"][ch] == sd["token"]
            else:  # a sweep belongs to the sample that follows it (or the last one)
                assert sample["timestamp"] >= sd["timestamp"] or sample["next"] == ""
            pose = nusc.get("ego_pose", sd["ego_pose_token"])
            assert pose["timestamp"] == sd["timestamp"]
    stamps = [sd["timestamp"] for sd in nusc.sample_data]
    assert len(set(stamps)) == len(stamps)
    # Copied images are the source bytes.
    sd = nusc.get("sample_data", nusc.sample[1]["data"]["ring_side_left"])
    src = log_dir / "sensors" / "cameras" / "ring_side_left"
    assert any((src / p.name).read_bytes() == Path(nusc.get_sample_data_path(sd["token"])).read_bytes()
               for p in src.iterdir())


def test_ego_poses_are_the_ground_level_truth(nusc: NuScenes, synthetic):
    """Each reading's ego pose is the world's ego pose at that reading's own ns time, 0.32 m lower."""
    _, world, out = synthetic
    offset = _global_to_city(out)
    times = {"LIDAR_TOP": world.timeline.sweeps_ns, **world.timeline.images_ns}
    for ch, ts_ns in times.items():
        sds = sorted((sd for sd in nusc.sample_data if sd["channel"] == ch), key=lambda sd: sd["timestamp"])
        assert [sd["timestamp"] for sd in sds] == [int(t) // 1000 for t in ts_ns] or ch != "LIDAR_TOP"
        for sd, t in zip(sds, ts_ns):
            pose = nusc.get("ego_pose", sd["ego_pose_token"])
            truth = world.city_T_ego_at(int(t))
            assert np.allclose(np.array(pose["translation"]) + offset, truth[:3, 3] - [0, 0, 0.32], atol=1e-9)
            assert np.allclose(quat_to_rot(pose["rotation"]), truth[:3, :3], atol=1e-12)
            assert abs(sd["timestamp"] - int(t) // 1000) <= 3  # µs label: truncated, bumped on collision


def test_boxes_velocities_and_attributes_follow_the_actors(nusc: NuScenes, synthetic):
    log_dir, world, out = synthetic
    offset = _global_to_city(out)
    actors = {a.track_uuid: a for a in world.actors}
    names = {a["token"]: a["name"] for a in nusc.attribute}
    seen_moving = seen_parked = 0
    for ann in nusc.sample_annotation:
        uuid = next(u for u in actors if make_token(log_dir.name, "instance", u) == ann["instance_token"])
        actor = actors[uuid]
        sample = nusc.get("sample", ann["sample_token"])
        poses = world.actor_poses_at(sample["timestamp"] * 1000)
        k = poses.track_uuid.index(uuid)
        assert np.allclose(np.array(ann["translation"]) + offset, poses.city_T_box[k, :3, 3], atol=1e-6)
        assert ann["size"] == pytest.approx([actor.size_lwh[1], actor.size_lwh[0], actor.size_lwh[2]])
        attr = names[ann["attribute_tokens"][0]]
        if actor.category == "REGULAR_VEHICLE":
            assert attr == ("vehicle.moving" if actor.speed > 0 else "vehicle.parked")
            seen_moving += actor.speed > 0
            seen_parked += actor.speed == 0
        else:
            assert attr == "pedestrian.moving"
        v = nusc.box_velocity(ann["token"])
        if ann["prev"] or ann["next"]:
            assert np.linalg.norm(v[:2]) == pytest.approx(actor.speed, abs=1e-6)
    assert seen_moving and seen_parked


def test_get_boxes_interpolates_on_sweeps(nusc: NuScenes, synthetic):
    _, world, out = synthetic
    offset = _global_to_city(out)
    sd = nusc.get("sample_data", nusc.get("sample_data", nusc.sample[2]["data"]["LIDAR_TOP"])["prev"])
    assert not sd["is_key_frame"]
    boxes = nusc.get_boxes(sd["token"])
    assert boxes
    truth = world.actor_poses_at(sd["timestamp"] * 1000)
    for box in boxes:
        d = np.linalg.norm(truth.city_T_box[:, :3, 3] - (box.center + offset), axis=1)
        assert d.min() < 1e-3  # linear motion: the devkit's interpolation is exact up to the µs label


def test_devkit_renders_and_gt_detection_scores_1(nusc: NuScenes, synthetic, tmp_path):
    from nuscenes.eval.common.config import config_factory
    from nuscenes.eval.detection.evaluate import DetectionEval
    from nuscenes.eval.detection.utils import category_to_detection_name

    sample = nusc.sample[1]
    nusc.render_sample_data(sample["data"]["LIDAR_TOP"], out_path=str(tmp_path / "lidar.png"), verbose=False)
    nusc.render_sample_data(sample["data"]["ring_front_center"], out_path=str(tmp_path / "cam.png"),
                            verbose=False)
    assert (tmp_path / "lidar.png").stat().st_size > 5_000 and (tmp_path / "cam.png").stat().st_size > 5_000
    _, cam_boxes, _ = nusc.get_sample_data(sample["data"]["ring_front_center"])
    assert cam_boxes  # the lead car is in front of the ego

    attr_names = {a["token"]: a["name"] for a in nusc.attribute}
    results = {}
    for s in nusc.sample:
        results[s["token"]] = []
        for tok in s["anns"]:
            ann = nusc.get("sample_annotation", tok)
            det = category_to_detection_name(ann["category_name"])
            results[s["token"]].append({
                "sample_token": s["token"], "translation": ann["translation"], "size": ann["size"],
                "rotation": ann["rotation"], "velocity": np.nan_to_num(nusc.box_velocity(tok)[:2]).tolist(),
                "detection_name": det, "detection_score": 0.5, "num_pts": ann["num_lidar_pts"],
                "attribute_name": attr_names[ann["attribute_tokens"][0]]})
    path = tmp_path / "results.json"
    meta = {"use_camera": True, "use_lidar": False, "use_radar": False, "use_map": False,
            "use_external": False}
    path.write_text(json.dumps({"meta": meta, "results": results}))
    ev = DetectionEval(nusc, config_factory("detection_cvpr_2019"), str(path), "av2_train",
                       str(tmp_path / "e"), verbose=False)
    present = {b.detection_name for b in ev.gt_boxes.all}
    assert {"car", "pedestrian"} <= present
    metrics, _ = ev.evaluate()
    assert np.mean([metrics.mean_dist_aps[c] for c in present]) == pytest.approx(1.0)
    assert metrics.get_label_tp("car", "trans_err") == pytest.approx(0.0, abs=1e-9)


def test_conformance_checker_accepts_the_database(synthetic):
    from nuav2.nuscenes_db.validate import validate_database

    report = validate_database(synthetic[2], VERSION, devkit=True)
    assert report.ok, report.format_text()
    assert report.table_counts["sample"] == 4
