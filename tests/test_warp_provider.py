"""Warp mode end to end on a synthetic log: against the world's ground truth, the rotation baseline, the
map's paint, and through the nuScenes writer into an unmodified NuScenes() and ``validate``."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from nuscenes.nuscenes import NuScenes

from nuav2.bench.modes import rotation_frame_fn
from nuav2.bench.paint_alignment import paint_offsets_px, painted_boundary_points
from nuav2.evaluate.image_metrics import psnr
from nuav2.geometry import egoS_T_egoT_from_heights, quat_to_rot
from nuav2.nuscenes_db.images import ImageSourceError
from nuav2.nuscenes_db.writer import WriterOptions, write_log
from nuav2.rig import load_rig
from nuav2.scene import CameraFrame
from nuav2.warp.provider import WarpConfig, WarpRenderer, read_rgb, warp_image_source

VERSION = "v1.0-warp-test"
RIG_SCALE = 0.12  # nuScenes 1600x900 -> 192x108, about the angular resolution of the 1/8-scale AV2 images


@pytest.fixture(scope="module")
def synth_log(tmp_path_factory) -> Path:
    from nuav2.synth import SynthConfig, generate_log

    return generate_log(tmp_path_factory.mktemp("warp_av2"), seed=5, config=SynthConfig(seconds=1.0))


@pytest.fixture(scope="module")
def synth(synth_log: Path):
    from converters.av2 import read_log
    from nuav2.synth import load_world

    return read_log(synth_log), load_world(synth_log)


@pytest.fixture(scope="module")
def rig():
    return load_rig("nuscenes", scale=RIG_SCALE)


@pytest.fixture(scope="module")
def renders(synth, rig):
    """Per (channel, time): warp, ground truth, rotation baseline, and the target pose (two sample times)."""
    from nuav2.synth import render_view

    scene, world = synth
    renderer = WarpRenderer(scene)
    rotation = rotation_frame_fn(scene, mosaic=False)
    egoS_T_egoT = egoS_T_egoT_from_heights(scene.rig.origin_height_m, rig.origin_height_m)
    out = {}
    for t in scene.sweep_timestamps_ns[[3, 7]]:
        t = int(t)
        for cam in rig.cameras:
            city_T_cam = scene.city_T_ego_at(t) @ egoS_T_egoT @ cam.ego_T_cam
            warped = renderer(cam.channel, cam, city_T_cam, t)
            rotated = rotation([(cam, city_T_cam)], t)[0]
            out[(cam.channel, t)] = (warped, render_view(world, cam, city_T_cam, t), rotated, city_T_cam)
    return renderer, out


def test_warp_beats_the_rotation_baseline_on_every_camera(renders, rig):
    """Measured on the default scene: the warp leads the rotation homography by 5.6-13 dB per camera."""
    renderer, out = renders
    for cam in rig.cameras:
        warp_db = [psnr(w, g, data_range=255) for (ch, _), (w, g, r, _) in out.items() if ch == cam.channel]
        rot_db = [psnr(r, g, data_range=255) for (ch, _), (w, g, r, _) in out.items() if ch == cam.channel]
        assert np.mean(warp_db) > np.mean(rot_db) + 4.0, (cam.channel, warp_db, rot_db)
    all_warp = [psnr(w, g, data_range=255) for w, g, _, _ in out.values()]
    assert np.mean(all_warp) > 24.0  # measured ~26-27 dB at this size; the floor leaves JPEG/noise slack
    cov = [v for d in renderer.coverage.values() for v in d.values()]
    assert len(cov) == len(out) and min(cov) > 0.6 and np.mean(cov) > 0.9


def test_warped_images_are_uint8_finite_and_deterministic(synth, rig, renders):
    scene, _ = synth
    _, out = renders
    (ch, t), (warped, _, _, city_T_cam) = next(iter(out.items()))
    assert warped.dtype == np.uint8 and warped.shape == (rig.camera(ch).height, rig.camera(ch).width, 3)
    again = WarpRenderer(scene)(ch, rig.camera(ch), city_T_cam, t)
    assert np.array_equal(again, warped)


def test_lane_paint_lands_on_the_map(synth):
    from nuav2.synth import render_view

    scene, world = synth
    rig = load_rig("nuscenes", scale=0.25)  # the paint detector needs lines a few pixels wide
    renderer = WarpRenderer(scene)
    pts, tangents = painted_boundary_points(scene.vector_map)
    assert len(pts) > 100
    t = int(scene.sweep_timestamps_ns[5])
    city_T_egoT = scene.city_T_ego_at(t) @ egoS_T_egoT_from_heights(scene.rig.origin_height_m, 0.0)
    warp_err, gt_err = [], []
    for cam in rig.cameras:
        city_T_cam = city_T_egoT @ cam.ego_T_cam
        warped = renderer(cam.channel, cam, city_T_cam, t)
        truth = render_view(world, cam, city_T_cam, t)
        warp_err.append(paint_offsets_px(warped, cam, city_T_cam, pts, tangents))
        gt_err.append(paint_offsets_px(truth, cam, city_T_cam, pts, tangents))
    warp_err, gt_err = np.concatenate(warp_err), np.concatenate(gt_err)
    assert len(warp_err) > 50 and len(gt_err) > 50
    # The ground truth sets the measure's floor (resolution, detector); the warp stays within 0.3 px of it.
    assert np.median(warp_err) < np.median(gt_err) + 0.3
    assert np.median(warp_err) < 1.0


def test_convert_mode_warp_loads_in_the_devkit_and_validates(synth_log: Path, tmp_path: Path):
    from nuav2.cli import main
    from nuav2.convert import ConvertOptions, convert_av2

    options = ConvertOptions(mode="warp", version=VERSION, keyframe_hz=2.0, rig="nuscenes", scale=0.1,
                             show_progress=False)
    report = convert_av2(synth_log, tmp_path, options)
    assert report.ok, report.failed
    nusc = NuScenes(VERSION, str(tmp_path), verbose=False)
    out_rig = load_rig("nuscenes", scale=0.1)
    assert len(nusc.sample) == 2
    sample = nusc.sample[0]
    assert set(sample["data"]) == {"LIDAR_TOP", *out_rig.camera_channels}
    for ch in out_rig.camera_channels:
        sd = nusc.get("sample_data", sample["data"][ch])
        assert (sd["width"], sd["height"]) == (160, 90) and sd["filename"].endswith(".jpg")
        img = read_rgb(tmp_path / sd["filename"], out_rig.camera(ch))
        assert img.std() > 10  # a real picture, not a constant fill
    # Every written camera image has its confidence, keyed by its sample_data token.
    import json

    quality = json.loads((tmp_path / VERSION / "nuav2_image_quality.json").read_text())
    cam_tokens = {sd["token"] for sd in nusc.sample_data if sd["sensor_modality"] == "camera"}
    assert set(quality) == cam_tokens
    assert all(0.0 <= v <= 1.0 for v in quality.values())
    assert main(["validate", str(tmp_path), "--version", VERSION, "--quiet"]) == 0


def test_image_source_records_coverage_and_fingerprints_its_config(synth, tmp_path: Path):
    scene, _ = synth
    out_rig = load_rig("nuscenes", scale=0.05)
    images = warp_image_source(scene)
    write_log(scene, out_rig, images, tmp_path, WriterOptions(keyframe_hz=5.0, show_progress=False))
    coverage = images.render.coverage
    assert set(coverage) == set(out_rig.camera_channels)
    assert all(len(v) == 5 and all(0.5 < c <= 1.0 for c in v.values()) for v in coverage.values())
    images.render.save_coverage(tmp_path / "coverage.json")
    assert (tmp_path / "coverage.json").read_text().count("CAM_") == 6
    assert images.fingerprint().startswith("render:warp:")
    assert warp_image_source(scene, WarpConfig(fill="color")).fingerprint() != images.fingerprint()


@pytest.mark.parametrize("cache_mb", [1024, 0])  # 0: every view leaves the cache at once (rebuilt on demand)
def test_two_render_threads_write_the_same_files_as_one(synth, tmp_path: Path, cache_mb: int):
    scene, _ = synth
    out_rig = load_rig("nuscenes", scale=0.05)
    written = {}
    for threads in (1, 2):
        images = warp_image_source(scene, WarpConfig(cache_mb=cache_mb), threads=threads)
        assert images.images_at_once == threads
        root = tmp_path / f"t{threads}"
        write_log(scene, out_rig, images, root, WriterOptions(keyframe_hz=5.0, show_progress=False))
        written[threads] = {p.relative_to(root).as_posix(): p.read_bytes()
                            for p in sorted(root.rglob("*.jpg"))}
        assert images.render.coverage and not images.render._making  # nothing left half-built
    assert len(written[1]) == 5 * 6 and written[2] == written[1]


def test_log_threads_give_a_log_two_threads_only_where_its_worker_has_two_cores():
    import os

    from nuav2.convert import ConvertOptions, log_threads

    cores = len(os.sched_getaffinity(0))
    assert log_threads(ConvertOptions(mode="warp")) == (2 if cores >= 2 else 1)
    assert log_threads(ConvertOptions(mode="warp", workers=max(cores, 1))) == 1
    assert log_threads(ConvertOptions(mode="warp", executor="ray")) == 1  # a 1-CPU task by default
    assert log_threads(ConvertOptions(mode="warp", executor="ray", cpus_per_task=2)) == 2


def test_missing_source_image_names_the_file(synth, rig, tmp_path: Path):
    scene, _ = synth
    ch = "ring_front_center"
    frames = list(scene.camera_frames[ch])
    frames = [CameraFrame(f.channel, f.timestamp_ns, Path("/nonexistent/missing.jpg")) for f in frames]
    broken = dataclasses.replace(scene, camera_frames={**scene.camera_frames, ch: frames})
    cam = rig.camera("CAM_FRONT")
    t = int(scene.sweep_timestamps_ns[2])
    city_T_cam = scene.city_T_ego_at(t) @ egoS_T_egoT_from_heights(0.32, 0.0) @ cam.ego_T_cam
    with pytest.raises(ImageSourceError, match="missing.jpg"):
        WarpRenderer(broken)("CAM_FRONT", cam, city_T_cam, t)
    # With two render threads the writer stops on the same one-line error, whichever thread read the file.
    with pytest.raises(ImageSourceError, match="missing.jpg"):
        write_log(broken, load_rig("nuscenes", scale=0.05), warp_image_source(broken, threads=2),
                  tmp_path, WriterOptions(keyframe_hz=5.0, show_progress=False))
    with pytest.raises(ImageSourceError, match="needs the source camera images"):
        WarpRenderer(dataclasses.replace(scene, camera_frames={}))


def test_without_lidar_or_boxes_the_ground_still_warps(synth, rig):
    scene, world = synth
    from nuav2.synth import render_view

    bare = dataclasses.replace(scene, load_lidar=None, annotations=scene.annotations.empty())
    cam = rig.camera("CAM_FRONT")
    t = int(scene.sweep_timestamps_ns[4])
    city_T_cam = scene.city_T_ego_at(t) @ egoS_T_egoT_from_heights(0.32, 0.0) @ cam.ego_T_cam
    out = WarpRenderer(bare, WarpConfig(use_ground_raster=False)).render(cam, city_T_cam, t)
    assert np.all(np.isfinite(out.rgb)) and out.coverage.mean() > 0.5
    gt = render_view(world, cam, city_T_cam, t).astype(np.float32) / 255
    lower = np.zeros(out.coverage.shape, bool)
    lower[-cam.height // 4:] = True  # the road just ahead: ground only, nothing on it
    assert psnr(out.rgb, gt, mask=lower & out.coverage) > 22.0


def test_a_pedestrian_in_view_is_recorded_and_lowers_the_confidence(synth, rig):
    """The walking pedestrian's box pixels are marked non-rigid and left out of the recorded confidence."""
    from nuav2.geometry import make_T

    scene, _ = synth
    ann = scene.annotations
    t = int(scene.sweep_timestamps_ns[4])
    rows = [r for r in ann.at(t) if str(ann.category[r]) == "PEDESTRIAN"]
    assert rows, "the default synthetic world has a walking pedestrian"
    ego_T_box = make_T(quat_to_rot(ann.ego_q_box[rows[0]]), ann.ego_t_box[rows[0]])
    centre = (scene.city_T_ego_at(t) @ ego_T_box)[:3, 3]
    # A camera 6 m west of the pedestrian, at chest height, looking east (+x) at it.
    cam = rig.camera("CAM_FRONT")
    R = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    city_T_cam = make_T(R, centre + [-6.0, 0.0, 0.3])
    renderer = WarpRenderer(scene)
    out = renderer.render(cam, city_T_cam, t)
    assert 0.01 < out.nonrigid.mean() < 0.5
    renderer("CAM_FRONT", cam, city_T_cam, t)
    assert renderer.nonrigid["CAM_FRONT"][t] == pytest.approx(out.nonrigid.mean())
    assert renderer.coverage["CAM_FRONT"][t] == pytest.approx((out.coverage & ~out.nonrigid).mean())
