"""``nuav2 convert av2 SRC OUT --mode truth``: the synthetic world rendered exactly in the target rig.

Oracle: every written camera image equals the world's ground-truth renderer (JPEG-encoded as
the writer encodes) at the pose built independently from the world (its ego trajectory, AV2's
0.32 m origin height, the nuScenes rig's extrinsics) at the sample_data timestamp; the
database's intrinsics and extrinsics are the rig's at the requested scale. A real AV2 log has
no world: one-line error, no traceback.
"""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from transfer_dbs import synthetic_truth_db

from nuav2.cli import main
from nuav2.geometry import T_from_quat_trans, translation_T
from nuav2.maptr.dataset import load_image_rgb
from nuav2.rig import load_rig
from nuav2.synth import load_world, render_view
from nuav2.synth.world import EGO_ORIGIN_HEIGHT_M

SCALE = 0.1


@pytest.fixture(scope="module")
def truth_db(tmp_path_factory):
    return synthetic_truth_db(tmp_path_factory.mktemp("truth"), seed=3, seconds=0.3, scale=SCALE)


def _jpeg_roundtrip(rgb: np.ndarray) -> np.ndarray:
    """The image as the writer stores it (OpenCV JPEG, quality 95), decoded."""
    ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(rgb[:, :, ::-1]), [cv2.IMWRITE_JPEG_QUALITY, 95])
    assert ok
    return cv2.imdecode(buf, cv2.IMREAD_COLOR)[:, :, ::-1].astype(np.float64)


def _table(out, name):
    return json.loads((out / "v1.0-nuav2" / f"{name}.json").read_text())


def test_truth_images_are_the_world_seen_by_the_target_rig(truth_db):
    log_dir, out = truth_db
    world = load_world(log_dir)
    rig = load_rig("nuscenes", SCALE)
    sensors = {s["token"]: s["channel"] for s in _table(out, "sensor")}
    calib = {c["token"]: c for c in _table(out, "calibrated_sensor")}
    cams = [sd for sd in _table(out, "sample_data") if sd["fileformat"] == "jpg"]
    assert len(cams) == 6 * 3  # 6 cameras at each of the 3 sweeps (every sweep is a sample)
    egoS_T_egoT = translation_T(
        0.0, 0.0, -EGO_ORIGIN_HEIGHT_M
    )  # AV2 origin 0.32 m up, nuScenes on the ground
    for sd in cams:
        cs = calib[sd["calibrated_sensor_token"]]
        cam = rig.camera(sensors[cs["sensor_token"]])
        np.testing.assert_allclose(np.asarray(cs["camera_intrinsic"]), cam.K, atol=1e-9)
        city_T_cam = world.city_T_ego_at(int(sd["timestamp"]) * 1000) @ egoS_T_egoT @ cam.ego_T_cam
        expected = _jpeg_roundtrip(render_view(world, cam, city_T_cam, int(sd["timestamp"]) * 1000))
        got = load_image_rgb(str(out / sd["filename"])).astype(np.float64)
        assert got.shape == expected.shape == (cam.height, cam.width, 3)
        # the same pixels but for edges that float rounding of the stored poses can shift (~0.05 mean)
        assert np.abs(got - expected).mean() < 0.25, sd["filename"]
        # a camera 0.2 m off would be told apart (the comparison is not blind)
        moved = _jpeg_roundtrip(
            render_view(world, cam, city_T_cam @ translation_T(0.2, 0.0, 0.0), int(sd["timestamp"]) * 1000)
        )
        assert np.abs(got - moved).mean() > 2.0
        # ... and the database's own calibration says the same pose
        np.testing.assert_allclose(
            T_from_quat_trans(cs["rotation"], cs["translation"]), cam.ego_T_cam, atol=1e-9
        )


def test_truth_mode_differs_from_the_source_cameras(truth_db):
    """Guard against a no-op: a truth image is not the nearest AV2 camera's picture."""
    log_dir, out = truth_db
    front = sorted((out / "samples" / "CAM_FRONT").iterdir())[0]
    src = sorted((log_dir / "sensors" / "cameras" / "ring_front_center").iterdir())[0]
    a, b = load_image_rgb(str(front)), load_image_rgb(str(src))
    assert a.shape != b.shape


def test_truth_mode_refuses_a_log_without_a_world(
    av2_fixture_log, av2_fixture_calibration, tmp_path, capsys, caplog
):
    rc = main(
        [
            "convert",
            "av2",
            str(av2_fixture_log),
            str(tmp_path / "db"),
            "--mode",
            "truth",
            "--calibration",
            str(av2_fixture_calibration),
            "--allow-missing-cameras",
            "--no-progress",
        ]
    )
    err = capsys.readouterr().err + caplog.text  # the per-log failure is logged, the summary printed
    assert rc != 0
    assert "--mode truth needs a synthetic log" in err and str(av2_fixture_log) in err
    assert "Traceback" not in err
    report = json.loads((tmp_path / "db" / "convert_report.json").read_text())
    assert report["failed"] and "synthetic_world.json" in report["failed"][0]["error"]
