"""End to end on databases our converter wrote: info export, torch dataset, joint datasets, viz, bench.

A synthetic AV2 log (nuav2.synth, 0.5 s, 7 ring cameras) converted with
``nuav2 convert av2 --mode native`` is the image-bearing dataroot; the real AV2 fixture log
(no images) converted the same way is the second dataroot for joint training.
"""

from __future__ import annotations

import json
import pickle
from pathlib import Path

import numpy as np
import pytest
import torch
from pyquaternion import Quaternion

from nuav2.cli import main
from nuav2.maptr.dataset import MapSampleDataset, collate_map_samples, joint_dataset, load_image_rgb
from nuav2.maptr.fixed_points import resample_polyline
from nuav2.maptr.infos import NUSCENES_CAMERAS, info_filename, lidar2img
from nuav2.maptr.vectorize import CLASS_IDS, CLASSES

VERSION = "v1.0-nuav2"
# What MapTRv2's dataset (get_data_info) and temporal queue read from an info record.
MAPTR_INFO_KEYS = {
    "token",
    "lidar_path",
    "sweeps",
    "ego2global_translation",
    "ego2global_rotation",
    "lidar2ego_translation",
    "lidar2ego_rotation",
    "prev",
    "next",
    "scene_token",
    "can_bus",
    "frame_idx",
    "timestamp",
    "map_location",
    "annotation",
    "cams",
}
MAPTR_CAM_KEYS = {
    "data_path",
    "type",
    "sample_data_token",
    "sensor2ego_translation",
    "sensor2ego_rotation",
    "ego2global_translation",
    "ego2global_rotation",
    "timestamp",
    "sensor2lidar_rotation",
    "sensor2lidar_translation",
    "cam_intrinsic",
}


@pytest.fixture(scope="module")
def synthetic_db(tmp_path_factory) -> Path:
    from nuav2.convert import ConvertOptions, convert_av2
    from nuav2.synth import SynthConfig, generate_log

    base = tmp_path_factory.mktemp("maptr_synthetic")
    config = SynthConfig(seconds=0.5, lidar_azimuth_steps=32, n_parked=1, n_moving=0, n_pedestrians=0)
    log_dir = generate_log(base / "av2", seed=1, config=config)
    convert_av2(log_dir, base / "db", ConvertOptions(version=VERSION, show_progress=False))
    (base / "db" / "source_log.txt").write_text(str(log_dir))  # for the av2-side check below
    return base / "db"


@pytest.fixture(scope="module")
def nuscenes_rig_db(synthetic_db) -> Path:
    """The same synthetic log written in the nuScenes rig (six CAM_*, 16:9, render mode): the writer with
    the synthetic world's ground-truth renderer as its image source, keyframes at 5 Hz."""
    from converters.av2 import read_log
    from nuav2.nuscenes_db import shards
    from nuav2.nuscenes_db.images import RenderedImages
    from nuav2.nuscenes_db.merge import merge_shards
    from nuav2.nuscenes_db.writer import WriterOptions, write_log
    from nuav2.rig import load_rig
    from nuav2.synth import load_world, render_view

    log_dir = Path((synthetic_db / "source_log.txt").read_text())
    out = synthetic_db.parent / "nuscenes_rig"
    world = load_world(log_dir)
    images = RenderedImages(
        lambda ch, cam, city_T_cam, ts: render_view(world, cam, city_T_cam, ts), "synthetic"
    )
    shard = write_log(
        read_log(log_dir),
        load_rig("nuscenes", scale=0.05),
        images,
        out,
        WriterOptions(keyframe_hz=5, show_progress=False),
    )
    shard_dir = shards.shard_dir(out, VERSION, log_dir.name)
    shards.save_shard(shard_dir, shard, "test")
    merge_shards(out, VERSION, {log_dir.name: shard_dir}, {log_dir.name: "scene-0000"})
    return out


@pytest.fixture(scope="module")
def fixture_db(av2_fixture_log, av2_fixture_calibration, tmp_path_factory) -> Path:
    from nuav2.convert import ConvertOptions, convert_av2

    out = tmp_path_factory.mktemp("maptr_fixture_db")
    convert_av2(
        av2_fixture_log,
        out,
        ConvertOptions(
            version=VERSION,
            calibration_dir=av2_fixture_calibration,
            require_cameras=False,
            show_progress=False,
        ),
    )
    return out


@pytest.fixture(scope="module")
def nusc(synthetic_db):
    from nuscenes.nuscenes import NuScenes

    return NuScenes(version=VERSION, dataroot=str(synthetic_db), verbose=False)


@pytest.fixture(scope="module")
def infos(synthetic_db, tmp_path_factory) -> dict:
    out = tmp_path_factory.mktemp("maptr_infos")
    assert (
        main(["infos", str(synthetic_db), "--version", VERSION, "--out", str(out), "--prefix", "nuav2"]) == 0
    )
    splits = json.loads((synthetic_db / VERSION / "splits.json").read_text())
    return {s: pickle.loads((out / info_filename("nuav2", s)).read_bytes()) for s in splits}


def _global_T(record: dict) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Quaternion(record["rotation"]).rotation_matrix
    T[:3, 3] = record["translation"]
    return T


# ------------------------------------------------------------------ info export


def test_infos_have_maptr_fields_for_every_split_keyframe(infos, nusc, synthetic_db):
    splits = json.loads((synthetic_db / VERSION / "splits.json").read_text())
    for split, data in infos.items():
        assert data["metadata"] == {"version": VERSION}
        names = splits[split]
        expected = [s["token"] for s in nusc.sample if nusc.get("scene", s["scene_token"])["name"] in names]
        assert sorted(i["token"] for i in data["infos"]) == sorted(expected)
        for k, info in enumerate(data["infos"]):
            assert MAPTR_INFO_KEYS <= set(info)
            assert Path(info["lidar_path"]).is_file() and info["lidar_path"].endswith(".pcd.bin")
            assert info["frame_idx"] == k  # one scene: frame index = position in time
            assert set(info["annotation"]) == set(CLASSES)
            assert info["map_location"] == nusc.log[0]["location"]
            assert len(info["sweeps"]) <= 10
            for cam in info["cams"].values():
                assert MAPTR_CAM_KEYS <= set(cam) and Path(cam["data_path"]).is_file()
                assert cam["sensor2lidar_rotation"].shape == (3, 3) and cam["cam_intrinsic"].shape == (3, 3)


def test_info_can_bus_holds_the_pose_fields_and_an_accelerometer_reading(infos):
    info = infos["all"]["infos"][2]
    cb = info["can_bus"]
    assert cb.shape == (18,)
    np.testing.assert_allclose(cb[:3], info["ego2global_translation"])
    np.testing.assert_allclose(cb[3:7], info["ego2global_rotation"])
    assert cb[9] == pytest.approx(9.81, abs=0.5) and np.all(np.isfinite(cb))  # gravity on a near-level car
    yaw = Quaternion(info["ego2global_rotation"]).yaw_pitch_roll[0]
    assert cb[-1] == pytest.approx(np.degrees(yaw) % 360.0) and cb[-2] == pytest.approx(np.radians(cb[-1]))


def test_lidar2img_equals_the_devkit_point_chain(infos, nusc):
    """Oracle: lidar -> ego(lidar time) -> global -> ego(camera time) -> camera -> K, with pyquaternion
    on the raw tables (as the devkit's map_pointcloud_to_image), against MapTR's lidar2img."""
    rng = np.random.default_rng(0)
    pts_lidar = np.column_stack(
        [rng.uniform(-20, 20, 200), rng.uniform(-40, 40, 200), rng.uniform(-2, 3, 200)]
    )
    info = infos["all"]["infos"][3]
    sample = nusc.get("sample", info["token"])
    lsd = nusc.get("sample_data", sample["data"]["LIDAR_TOP"])
    global_T_lidar = _global_T(nusc.get("ego_pose", lsd["ego_pose_token"])) @ _global_T(
        nusc.get("calibrated_sensor", lsd["calibrated_sensor_token"])
    )
    assert info["cams"]
    for ch, cam in info["cams"].items():
        sd = nusc.get("sample_data", sample["data"][ch])
        cs = nusc.get("calibrated_sensor", sd["calibrated_sensor_token"])
        cam_T_global = np.linalg.inv(_global_T(nusc.get("ego_pose", sd["ego_pose_token"])) @ _global_T(cs))
        p = (cam_T_global @ global_T_lidar @ np.column_stack([pts_lidar, np.ones(200)]).T)[:3]
        uv_devkit = (np.asarray(cs["camera_intrinsic"]) @ p)[:2] / p[2]
        q = lidar2img(cam) @ np.column_stack([pts_lidar, np.ones(200)]).T
        np.testing.assert_allclose(q[:2] / q[2], uv_devkit, atol=1e-6, err_msg=ch)
        assert sd["timestamp"] != lsd["timestamp"] or ch == "LIDAR_TOP"  # cameras have their own ego pose


def test_sweep_sensor2lidar_maps_sweep_points_into_the_keyframe_lidar(infos, nusc):
    info = infos["all"]["infos"][-1]
    assert info["sweeps"], "the last keyframe has previous sweeps"
    sample = nusc.get("sample", info["token"])
    lsd = nusc.get("sample_data", sample["data"]["LIDAR_TOP"])
    lidar_T_global = np.linalg.inv(
        _global_T(nusc.get("ego_pose", lsd["ego_pose_token"]))
        @ _global_T(nusc.get("calibrated_sensor", lsd["calibrated_sensor_token"]))
    )
    p = np.array([3.0, 12.0, -1.0, 1.0])
    for sweep in info["sweeps"]:
        sd = nusc.get("sample_data", sweep["sample_data_token"])
        global_T_sweep = _global_T(nusc.get("ego_pose", sd["ego_pose_token"])) @ _global_T(
            nusc.get("calibrated_sensor", sd["calibrated_sensor_token"])
        )
        expected = (lidar_T_global @ global_T_sweep @ p)[:3]
        got = sweep["sensor2lidar_rotation"] @ p[:3] + sweep["sensor2lidar_translation"]
        np.testing.assert_allclose(got, expected, atol=1e-9)
        assert sweep["timestamp"] < info["timestamp"]


def test_info_annotation_is_the_vectorized_gt(infos, synthetic_db):
    from nuav2.maptr.vectorize import gt_vectors_for_split

    gt = gt_vectors_for_split(synthetic_db, VERSION, "all")
    for info in infos["all"]["infos"]:
        ann = info["annotation"]
        flat = [(c, p) for c in CLASSES for p in ann[c]]
        assert sorted((c, p.tobytes()) for c, p in flat) == sorted(
            (c, p.tobytes()) for c, p in gt[info["token"]]
        )
    assert all(infos["all"]["infos"][0]["annotation"][c] for c in CLASSES)  # the synthetic map has all four


def test_infos_for_unknown_split_name_the_splits_file(synthetic_db, tmp_path, capsys):
    argv = ["infos", str(synthetic_db), "--version", VERSION, "--out", str(tmp_path), "--splits", "nope"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "splits.json" in err and len(err.strip().splitlines()) == 1


# ------------------------------------------------------------------ torch dataset


def test_dataset_item_matches_infos_and_images(synthetic_db, nusc, infos):
    ds = MapSampleDataset(synthetic_db, VERSION, "all", nusc=nusc)
    assert len(ds) == len(infos["all"]["infos"])
    item = ds[1]
    info = next(i for i in infos["all"]["infos"] if i["token"] == item["sample_token"])
    assert item["cam_names"] == list(info["cams"])  # AV2-native: the ring, sorted (not nuScenes' six)
    assert not set(item["cam_names"]) & set(NUSCENES_CAMERAS)
    n = len(item["cam_names"])
    assert item["img"].dtype == torch.uint8 and item["img"].shape[:2] == (n, 3)
    for k, ch in enumerate(item["cam_names"]):
        sd = nusc.get("sample_data", nusc.get("sample", item["sample_token"])["data"][ch])
        h, w = item["img_shape"][k].tolist()
        assert (w, h) == (sd["width"], sd["height"])
        raw = load_image_rgb(str(synthetic_db / sd["filename"]))
        assert torch.equal(item["img"][k, :, :h, :w], torch.from_numpy(raw).permute(2, 0, 1))
        assert torch.all(item["img"][k, :, h:, :] == 0) and torch.all(item["img"][k, :, :, w:] == 0)
        np.testing.assert_allclose(
            item["lidar2img"][k].numpy(), lidar2img(info["cams"][ch]), rtol=1e-6, atol=1e-3
        )
    assert item["ego2global"].dtype == torch.float64
    np.testing.assert_allclose(item["ego2global"][:3, 3].numpy(), info["ego2global_translation"])
    np.testing.assert_allclose(item["lidar2ego"][:3, 3].numpy(), info["lidar2ego_translation"])


def test_dataset_gt_targets_are_the_resampled_vectors(synthetic_db, nusc):
    item = MapSampleDataset(synthetic_db, VERSION, "all", nusc=nusc, load_images=False)[0]
    vectors = item["gt_vectors"]
    assert item["gt_labels"].tolist() == [CLASS_IDS[c] for c, _ in vectors]
    assert item["gt_pts"].shape == (len(vectors), 20, 2) and item["gt_shifts_pts"].shape == (
        len(vectors),
        19,
        20,
        2,
    )
    for k, (_cls, pts) in enumerate(vectors):
        expected = np.clip(resample_polyline(pts, 20), [-15, -30], [15, 30])
        np.testing.assert_allclose(item["gt_pts"][k].numpy(), expected, atol=1e-5)
        assert torch.equal(item["gt_shifts_pts"][k, 0], item["gt_pts"][k])
    assert torch.all(torch.isfinite(item["gt_pts"]))


def _front_camera_brightness(ds: MapSampleDataset, cls: str, shift_x_m: float = 0.0) -> list[float]:
    """Gray values where ``cls`` GT 6-25 m ahead (moved sideways by ``shift_x_m``) hits the front camera."""
    from nuav2.viz import densify, ground_points_lidar

    vals: list[float] = []
    for i in range(len(ds)):
        item = ds[i]
        k = item["cam_names"].index("ring_front_center")
        gray = item["img"][k].float().mean(0).numpy()
        h, w = item["img_shape"][k].tolist()
        for c, p in item["gt_vectors"]:
            if c != cls:
                continue
            xyz = ground_points_lidar(densify(p, 0.25) + [shift_x_m, 0.0], item["lidar2ego"].numpy())
            xyz = xyz[(xyz[:, 1] > 6) & (xyz[:, 1] < 25)]
            q = np.column_stack([xyz, np.ones(len(xyz))]) @ item["lidar2img"][k].double().numpy().T
            uv = np.round(q[:, :2] / q[:, 2:3]).astype(int)
            ok = (q[:, 2] > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
            vals += gray[uv[ok, 1], uv[ok, 0]].tolist()
    return vals


def test_gt_dividers_land_on_painted_pixels(synthetic_db, nusc):
    """Poses, lidar2img and the GT frame together: divider GT projects onto lane paint, brighter than
    lane centerlines (asphalt) and than the same dividers moved 0.6 m sideways, in every keyframe."""
    ds = MapSampleDataset(synthetic_db, VERSION, "all", nusc=nusc)
    on_paint = _front_camera_brightness(ds, "divider")
    asphalt = _front_camera_brightness(ds, "centerline")
    beside = _front_camera_brightness(ds, "divider", 0.6) + _front_camera_brightness(ds, "divider", -0.6)
    assert len(on_paint) > 50 and len(asphalt) > 50
    assert np.mean(on_paint) > np.mean(asphalt) + 20, (np.mean(on_paint), np.mean(asphalt))
    assert np.mean(on_paint) > np.mean(beside) + 20, (np.mean(on_paint), np.mean(beside))


def test_fraction_subset_and_joint_dataset(synthetic_db, fixture_db, nusc):
    full = MapSampleDataset(synthetic_db, VERSION, "all", nusc=nusc)
    sub = MapSampleDataset(synthetic_db, VERSION, "all", nusc=nusc, fraction=0.05, seed=0)
    assert sub.scene_names == full.scene_names and len(sub) == len(full)  # one scene: at least one kept
    other = MapSampleDataset(fixture_db, VERSION, "all", load_images=False)
    both = joint_dataset([full, other])
    assert len(both) == len(full) + len(other)
    a, b = both[0], both[len(full)]
    assert a["map_location"] != b["map_location"] and a.keys() - {"img", "img_shape"} == b.keys()
    assert b["lidar2img"].shape == (0, 4, 4)  # the fixture log has no camera images
    assert {c for c, _ in b["gt_vectors"]} == set(CLASSES)
    loader = torch.utils.data.DataLoader(full, batch_size=2, collate_fn=collate_map_samples)
    batch = next(iter(loader))
    assert batch["img"].shape[0] == 2 and batch["lidar2img"].shape[:2] == (2, len(a["cam_names"]))
    assert len(batch["gt_pts"]) == 2 and len(batch["sample_token"]) == 2
    with pytest.raises(ValueError, match="classes"):
        joint_dataset([full, MapSampleDataset(synthetic_db, VERSION, "all", nusc=nusc, classes=CLASSES[:3])])


def test_dataset_index_and_image_scale(synthetic_db, nusc):
    ds = MapSampleDataset(synthetic_db, VERSION, "all", nusc=nusc, image_scale=0.5)
    item = ds[-1]
    full = MapSampleDataset(synthetic_db, VERSION, "all", nusc=nusc)[len(ds) - 1]
    assert item["sample_token"] == full["sample_token"]
    np.testing.assert_allclose(
        item["cam_intrinsic"][:, :2].numpy(), full["cam_intrinsic"][:, :2].numpy() * 0.5, rtol=1e-6
    )
    assert item["img"].shape[-1] == round(full["img"].shape[-1] * 0.5)
    with pytest.raises(IndexError):
        ds[len(ds)]


def test_synthetic_gt_matches_the_av2_map_api_at_every_keyframe(synthetic_db, nusc):
    """The synthetic world has an intersection (lane connectors, turning centerlines, four crossings)."""
    from av2.map.map_api import ArgoverseStaticMap

    from nuav2.geometry import translation_T
    from nuav2.maptr.av2_reference import av2_reference_vectors, class_chamfer
    from nuav2.maptr.vectorize import global_T_lidar_of_sample, gt_vectors_for_split

    log_dir = Path((synthetic_db / "source_log.txt").read_text())
    av2_map = ArgoverseStaticMap.from_map_dir(log_dir / "map", build_raster=False)
    (meta,) = json.loads((synthetic_db / VERSION / "nuav2_logs.json").read_text())
    city_T_global = translation_T(*meta["city_offset"])
    gt = gt_vectors_for_split(synthetic_db, VERSION, "all")
    for token, ours in gt.items():
        ref = av2_reference_vectors(av2_map, city_T_global @ global_T_lidar_of_sample(nusc, token))
        for cls, (mean, _) in class_chamfer(ours, ref).items():
            assert mean < 0.05, f"{token}: {cls} chamfer {mean:.4f} m"


def test_nuscenes_rig_database_gives_maptr_cameras_and_projections(nuscenes_rig_db, synthetic_db, nusc):
    from nuscenes.nuscenes import NuScenes

    nusc_rig = NuScenes(version=VERSION, dataroot=str(nuscenes_rig_db), verbose=False)
    ds = MapSampleDataset(nuscenes_rig_db, VERSION, "all", nusc=nusc_rig)
    item = ds[1]
    assert item["cam_names"] == list(NUSCENES_CAMERAS)  # MapTR's order
    assert item["img"].shape == (6, 3, 45, 80) and torch.all(item["img_shape"] == torch.tensor([45, 80]))
    rng = np.random.default_rng(1)
    pts = np.column_stack(
        [rng.uniform(-15, 15, 50), rng.uniform(-30, 30, 50), rng.uniform(-2, 1, 50), np.ones(50)]
    )
    sample = nusc_rig.get("sample", item["sample_token"])
    lsd = nusc_rig.get("sample_data", sample["data"]["LIDAR_TOP"])
    global_T_lidar = _global_T(nusc_rig.get("ego_pose", lsd["ego_pose_token"])) @ _global_T(
        nusc_rig.get("calibrated_sensor", lsd["calibrated_sensor_token"])
    )
    for k, ch in enumerate(item["cam_names"]):
        sd = nusc_rig.get("sample_data", sample["data"][ch])
        cs = nusc_rig.get("calibrated_sensor", sd["calibrated_sensor_token"])
        p = (
            np.linalg.inv(_global_T(nusc_rig.get("ego_pose", sd["ego_pose_token"])) @ _global_T(cs))
            @ global_T_lidar
            @ pts.T
        )[:3]
        q = item["lidar2img"][k].double().numpy() @ pts.T
        front = p[2] > 1.0  # float32 lidar2img: compare where the depth does not magnify rounding
        uv_devkit = (np.asarray(cs["camera_intrinsic"]) @ p)[:2] / p[2]
        np.testing.assert_allclose((q[:2] / q[2])[:, front], uv_devkit[:, front], rtol=1e-5, atol=1e-3)
    # nuAV2-native and nuScenes-rig data in one loader (joint training)
    both = joint_dataset([MapSampleDataset(synthetic_db, VERSION, "all", nusc=nusc), ds])
    assert len(both) == 5 + len(ds)
    batch = collate_map_samples([both[0], both[len(both) - 1]])
    assert isinstance(batch["img"], list) and [b.shape[0] for b in batch["img"]] == [7, 6]
    assert batch["ego2global"].shape == (2, 4, 4)


# ------------------------------------------------------------------ viz and bench, end to end


def test_viz_cli_renders_gt_and_predictions(synthetic_db, nusc, tmp_path, capsys):
    import cv2

    token = nusc.sample[2]["token"]
    gt = MapSampleDataset(synthetic_db, VERSION, "all", nusc=nusc, load_images=False)[2]["gt_vectors"]
    preds = {
        "meta": {},
        "results": [
            {
                "sample_token": token,
                "vectors": [
                    {
                        "pts": (p + 0.5).tolist(),
                        "pts_num": len(p),
                        "cls_name": c,
                        "type": CLASS_IDS[c],
                        "confidence_level": 0.9,
                    }
                    for c, p in gt
                ],
            }
        ],
    }
    pred_path = tmp_path / "nuscmap_results.json"
    pred_path.write_text(json.dumps(preds))
    out = tmp_path / "viz.png"
    assert (
        main(
            [
                "viz",
                str(synthetic_db),
                "--version",
                VERSION,
                "--sample",
                token,
                "--out",
                str(out),
                "--pred",
                str(pred_path),
                "--tile-height",
                "120",
            ]
        )
        == 0
    )
    img = cv2.imread(str(out))
    assert img is not None and img.shape[0] == 240  # two rows of camera tiles, BEV panel as tall
    rgb = img[:, :, ::-1].reshape(-1, 3).astype(int)
    from nuav2.viz import CLASS_COLORS_RGB

    for cls, color in CLASS_COLORS_RGB.items():
        assert np.any(np.all(np.abs(rgb - np.array(color)) <= 2, axis=1)), f"no {cls} pixels drawn"
    capsys.readouterr()
    argv = ["viz", str(synthetic_db), "--version", VERSION, "--sample", "0" * 32, "--out", str(out)]
    assert main(argv) == 2
    assert "--sample" in capsys.readouterr().err


def test_bench_loader_prints_json(synthetic_db, capsys):
    assert main(["bench", "loader", str(synthetic_db), "--version", VERSION, "--samples", "3", "--json"]) == 0
    result = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert result["samples"] == 3 and result["cameras"] == 7 and result["locations"] == 1
    for key in ("samples_per_s", "gt_only_samples_per_s", "bare_read_samples_per_s", "ratio_vs_bare_read"):
        assert result[key] > 0 and np.isfinite(result[key])
    assert result["vectors_per_sample"] > 0


def test_timestamp_sort_interleaving_is_detected():
    from nuav2.maptr.infos import scenes_stay_contiguous_by_time

    a = [{"scene_token": "a", "timestamp": t} for t in (1, 2, 3)]
    b = [{"scene_token": "b", "timestamp": t} for t in (10, 11)]
    assert scenes_stay_contiguous_by_time(b + a)
    assert not scenes_stay_contiguous_by_time(a + [{"scene_token": "b", "timestamp": 2}])


def test_can_bus_yaw_wraps_into_0_360():
    from nuav2.maptr.infos import can_bus_from_pose

    q = [np.cos(-np.pi / 4), 0.0, 0.0, np.sin(-np.pi / 4)]  # yaw -90 deg
    cb = can_bus_from_pose([1.0, 2.0, 0.0], q)
    assert cb[-1] == pytest.approx(270.0) and cb[-2] == pytest.approx(1.5 * np.pi)
    assert np.all(np.isfinite(cb))
