"""Score a written database's camera images against a synthetic world's exact renders.

Poses come from the database itself (ego_pose + calibrated_sensor, read back from the JSON
as the devkit would), so this checks the whole chain: frame alignment, target extrinsics,
timestamps and the pixels.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nuav2.evaluate.image_metrics import psnr, ssim
from nuav2.geometry import F64, T_from_quat_trans, translation_T
from nuav2.maptr.dataset import load_image_rgb
from nuav2.rig import CameraSpec


@dataclass
class CameraScores:
    psnr_db: list[float] = field(default_factory=list)
    ssim: list[float] = field(default_factory=list)

    def summary(self) -> dict:
        return {"n": len(self.psnr_db), "psnr_db": float(np.mean(self.psnr_db)),
                "ssim": float(np.mean(self.ssim))}


@dataclass(frozen=True)
class WrittenImage:
    """One key-frame camera image of the database with everything needed to re-render it."""

    channel: str
    path: Path
    camera: CameraSpec
    city_T_cam: F64
    timestamp_ns: int


def key_camera_images(dataroot: Path, version: str, log_offsets: dict[str, np.ndarray]) -> list[WrittenImage]:
    """Key-frame camera images with city poses; ``log_offsets``: {log token: city_offset (x, y, z)}."""
    root = Path(dataroot) / version

    def table(name: str) -> dict[str, dict]:
        return {r["token"]: r for r in json.loads((root / f"{name}.json").read_text())}

    sensors, calibs, poses = table("sensor"), table("calibrated_sensor"), table("ego_pose")
    samples, scenes, logs = table("sample"), table("scene"), table("log")
    out = []
    for sd in json.loads((root / "sample_data.json").read_text()):
        calib = calibs[sd["calibrated_sensor_token"]]
        sensor = sensors[calib["sensor_token"]]
        if sensor["modality"] != "camera" or not sd["is_key_frame"]:
            continue
        log = logs[scenes[samples[sd["sample_token"]]["scene_token"]]["log_token"]]
        offset = log_offsets[log["token"]]
        pose = poses[sd["ego_pose_token"]]
        global_T_ego = T_from_quat_trans(pose["rotation"], pose["translation"])
        ego_T_cam = T_from_quat_trans(calib["rotation"], calib["translation"])
        city_T_cam = translation_T(*offset) @ global_T_ego @ ego_T_cam
        cam = CameraSpec(sensor["channel"], sd["width"], sd["height"], np.asarray(calib["camera_intrinsic"]),
                         ego_T_cam)
        out.append(WrittenImage(sensor["channel"], Path(dataroot) / sd["filename"], cam, city_T_cam,
                                int(sd["timestamp"]) * 1000))
    return out


def score_against_world(images: list[WrittenImage], world, every: int = 1) -> dict[str, CameraScores]:
    """Per-channel PSNR/SSIM of written images vs the world's render at the same pose and time."""
    from nuav2.synth import render_view

    scores: dict[str, CameraScores] = {}
    for im in images[::every]:
        gt = render_view(world, im.camera, im.city_T_cam, im.timestamp_ns).astype(np.float32) / 255.0
        got = load_image_rgb(str(im.path)).astype(np.float32) / 255.0
        s = scores.setdefault(im.channel, CameraScores())
        s.psnr_db.append(float(psnr(got, gt)))
        s.ssim.append(float(ssim(got, gt)))
    return scores


def log_offsets(dataroot: Path, version: str) -> dict[str, np.ndarray]:
    """{log token: city_offset (x, y, z)} from the converter's ``nuav2_logs.json`` sidecar."""
    from nuav2.nuscenes_db.map_frame import city_offset_of

    path = Path(dataroot) / version / "nuav2_logs.json"
    return {rec["log_token"]: city_offset_of(rec, str(path)) for rec in json.loads(path.read_text())}
