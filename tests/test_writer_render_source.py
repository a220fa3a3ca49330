"""The render-mode seam: a trivial renderer writes the nuScenes rig's cameras for the real fixture log."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from av2.utils.io import read_city_SE3_ego
from nuscenes.nuscenes import NuScenes
from pyquaternion import Quaternion

from nuav2.geometry import T_from_quat_trans, translation_T
from nuav2.nuscenes_db import shards
from nuav2.nuscenes_db.images import ImageSourceError, RenderedImages
from nuav2.nuscenes_db.merge import merge_shards
from nuav2.nuscenes_db.tokens import make_token
from nuav2.nuscenes_db.writer import WriterOptions, write_log
from nuav2.rig import CameraSpec, load_rig

VERSION = "v1.0-render-test"


def _T(record: dict) -> np.ndarray:
    return T_from_quat_trans(record["rotation"], record["translation"])


@pytest.fixture(scope="module")
def fixture_scene(av2_fixture_log: Path, av2_fixture_calibration: Path):
    from converters.av2 import read_log

    return read_log(av2_fixture_log, av2_fixture_calibration, require_cameras=False)


def test_trivial_renderer_gets_aligned_camera_poses(fixture_scene, av2_fixture_log: Path, tmp_path: Path):
    # Point counts unknown (-1): the writer counts them in the sweep; AV2's own counts are the oracle.
    ann = fixture_scene.annotations
    scene = dataclasses.replace(fixture_scene, annotations=dataclasses.replace(
        ann, num_interior_pts=np.full(len(ann), -1, np.int64)))
    out_rig = load_rig("nuscenes", scale=0.1)  # 160x90 images keep the test fast
    calls: list[tuple[str, int, np.ndarray]] = []

    def render(channel: str, camera: CameraSpec, city_T_cam: np.ndarray, timestamp_ns: int) -> np.ndarray:
        calls.append((channel, timestamp_ns, city_T_cam.copy()))
        img = np.zeros((camera.height, camera.width, 3), np.uint8)
        img[..., 0] = 40 * len(calls)  # something visible per call
        return img

    shard = write_log(scene, out_rig, RenderedImages(render, name="trivial"), tmp_path,
                      WriterOptions(show_progress=False))
    path = shards.shard_dir(tmp_path, VERSION, scene.log_id)
    shards.save_shard(path, shard, "fp")
    assert shards.is_complete(path, "fp") and not shards.is_complete(path, "other")
    merge_shards(tmp_path, VERSION, {scene.log_id: path}, {scene.log_id: "scene-0007"})
    nusc = NuScenes(VERSION, str(tmp_path), verbose=False)

    sweep_ns = int(scene.sweep_timestamps_ns[0])
    assert sorted(c[0] for c in calls) == sorted(out_rig.camera_channels)
    assert all(c[1] == sweep_ns for c in calls)
    sample = nusc.sample[0]
    assert set(sample["data"]) == {"LIDAR_TOP", *out_rig.camera_channels}
    offset = json.loads((tmp_path / VERSION / "nuav2_logs.json").read_text())[0]["city_offset"]
    city_T_global = translation_T(*offset)
    # Independent chain: av2's own pose at the sweep, ego origin dropped 0.32 m to the ground,
    # the nuScenes rig's camera extrinsic.
    city_T_egoS = read_city_SE3_ego(av2_fixture_log)[sweep_ns].transform_matrix
    city_T_egoT = city_T_egoS @ translation_T(z=-load_rig("av2").origin_height_m)
    for channel, _, city_T_cam in calls:
        sd = nusc.get("sample_data", sample["data"][channel])
        assert sd["is_key_frame"] and (sd["width"], sd["height"]) == (160, 90)
        written = city_T_global @ _T(nusc.get("ego_pose", sd["ego_pose_token"])) @ _T(
            nusc.get("calibrated_sensor", sd["calibrated_sensor_token"]))
        assert np.abs(written - city_T_cam).max() < 1e-9
        assert np.abs(city_T_egoT @ out_rig.camera(channel).ego_T_cam - city_T_cam).max() < 1e-9
        _, boxes, K = nusc.get_sample_data(sd["token"])
        assert np.allclose(K, out_rig.camera(channel).K)
    front = nusc.get("sample_data", sample["data"]["CAM_FRONT"])
    assert nusc.get("calibrated_sensor", front["calibrated_sensor_token"])["translation"] == pytest.approx(
        [1.70079118954, 0.0159456324149, 1.51095763913])
    lidar_sd = nusc.get("sample_data", sample["data"]["LIDAR_TOP"])
    lidar_cs = nusc.get("calibrated_sensor", lidar_sd["calibrated_sensor_token"])
    lidar_q = Quaternion(matrix=out_rig.lidar("LIDAR_TOP").ego_T_lidar[:3, :3])
    assert lidar_cs["rotation"] == pytest.approx(list(lidar_q))
    pose = nusc.get("ego_pose", lidar_sd["ego_pose_token"])
    # ground-level ego; global z = city z minus the ground height under the first pose
    assert pose["translation"][2] == pytest.approx(city_T_egoT[2, 3] - offset[2], abs=1e-9)
    assert abs(pose["translation"][2]) < 0.05
    pts, _, im = nusc.explorer.map_pointcloud_to_image(lidar_sd["token"], front["token"])
    assert im.size == (160, 90) and pts.shape[1] > 100

    av2 = pd.read_feather(av2_fixture_log / "annotations.feather")
    av2 = av2[(av2.timestamp_ns == sweep_ns) & (av2.category != "SIGN")]
    counted = {a["instance_token"]: a["num_lidar_pts"] for a in nusc.sample_annotation}
    assert len(counted) == len(av2) == 44
    for uuid, n in zip(av2.track_uuid, av2.num_interior_pts):
        assert counted[make_token(scene.log_id, "instance", uuid)] == n


def test_renderer_with_the_wrong_image_size_fails_the_log_and_cleans_up(fixture_scene, tmp_path: Path):
    scene = fixture_scene
    out_rig = load_rig("nuscenes", scale=0.05)

    def bad(channel, camera, city_T_cam, timestamp_ns):
        return np.zeros((camera.height + 1, camera.width, 3), np.uint8)

    with pytest.raises(ImageSourceError, match="expected uint8"):
        write_log(scene, out_rig, RenderedImages(bad), tmp_path, WriterOptions(show_progress=False))
    assert not any(p.is_file() for p in (tmp_path / "samples").rglob("*"))  # the sweep written first is gone
