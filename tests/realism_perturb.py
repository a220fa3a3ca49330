"""Real-data imperfections applied to an easy synthetic log in a test (independent of the realism presets):
per-image exposure and per-camera white balance on the source images, jittered box annotations,
noisy LiDAR. Each returns what it applied, so a test can check a correction against it."""

from __future__ import annotations

import shutil
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

from nuav2.scene import SceneLog


def copy_log(log_dir: Path, dst_root: Path) -> Path:
    """A copy of a synthetic AV2 log (and its world file) under ``dst_root`` with the same layout."""
    dst = Path(dst_root) / log_dir.parent.name / log_dir.name
    shutil.copytree(log_dir, dst)
    return dst


def perturb_exposure(log_dir: Path, seed: int = 0, drift: float = 0.25, white_balance: float = 0.12,
                     quality: int = 95) -> dict[str, dict[int, np.ndarray]]:
    """Rewrite every camera image with a gain per image (a smooth drift over time, log std ``drift``) times
    a white balance per camera (log std ``white_balance`` per channel), zero-mean in log over the log,
    like auto-exposure around a fixed target. Returns channel -> timestamp_ns -> RGB gain."""
    rng = np.random.default_rng(seed)
    cams = sorted(p for p in (log_dir / "sensors" / "cameras").iterdir() if p.is_dir())
    wb = {c.name: rng.normal(0, white_balance, 3) for c in cams}
    files = {c.name: sorted(c.glob("*.jpg")) for c in cams}
    log_gain: dict[str, dict[int, np.ndarray]] = {}
    for c in cams:
        n = len(files[c.name])
        phase, speed = rng.uniform(0, 2 * np.pi), rng.uniform(0.5, 1.5)
        drift_t = drift * np.sin(phase + speed * np.linspace(0, np.pi, n))
        log_gain[c.name] = {int(f.stem): wb[c.name] + drift_t[i] for i, f in enumerate(files[c.name])}
    mean = np.mean([g for d in log_gain.values() for g in d.values()], axis=0)
    out: dict[str, dict[int, np.ndarray]] = {}
    for c in cams:
        out[c.name] = {}
        for f in files[c.name]:
            gain = np.exp(log_gain[c.name][int(f.stem)] - mean)
            img = cv2.imread(str(f), cv2.IMREAD_COLOR).astype(np.float32)
            img *= gain[::-1][None, None, :]  # BGR
            img8 = np.clip(img + 0.5, 0, 255).astype(np.uint8)
            cv2.imwrite(str(f), img8, [cv2.IMWRITE_JPEG_QUALITY, quality])
            out[c.name][int(f.stem)] = gain
    return out


def jitter_boxes(scene: SceneLog, seed: int = 0, sigma_m: float = 0.08, sigma_yaw_rad: float = 0.015,
                 offset_m: float = 0.1) -> SceneLog:
    """The scene with every annotated box moved by a per-track offset plus per-frame jitter (in the ego
    frame) and turned by per-frame yaw jitter, as real labels are."""
    from nuav2.geometry import quat_multiply

    rng = np.random.default_rng(seed)
    ann = scene.annotations
    tracks = sorted(set(ann.track_id.tolist()))
    off = {t: rng.normal(0, offset_m, 3) * [1, 1, 0.3] for t in tracks}
    t_box = ann.ego_t_box + np.array([off[t] for t in ann.track_id.tolist()])
    t_box = t_box + rng.normal(0, sigma_m, t_box.shape) * [1, 1, 0.3]
    yaw = rng.normal(0, sigma_yaw_rad, len(t_box))
    dq = np.column_stack([np.cos(yaw / 2), np.zeros(len(yaw)), np.zeros(len(yaw)), np.sin(yaw / 2)])
    q_box = quat_multiply(ann.ego_q_box, dq)
    return replace(scene, annotations=replace(ann, ego_t_box=t_box, ego_q_box=q_box))


def noisy_lidar(scene: SceneLog, seed: int = 0, range_sigma_m: float = 0.04,
                dropout: float = 0.1) -> SceneLog:
    """The scene with LiDAR range noise (along each ray from the sensor) and random dropouts."""
    base = scene.load_lidar
    if base is None:
        return scene
    sensor = np.mean([lid.ego_T_lidar[:3, 3] for lid in scene.rig.lidars] or [np.zeros(3)], axis=0)

    def load(ref):
        sweep = base(ref)
        rng = np.random.default_rng([seed, int(ref.timestamp_ns) % (2**32)])
        xyz = np.asarray(sweep.xyz_ego, np.float64)
        keep = rng.random(len(xyz)) >= dropout
        d = xyz[keep] - sensor
        r = np.linalg.norm(d, axis=1, keepdims=True)
        xyz = sensor + d * (1 + rng.normal(0, range_sigma_m, r.shape) / np.maximum(r, 1e-6))
        return replace(sweep, xyz_ego=xyz, **{k: v[keep] for k, v in extra_columns(sweep).items()})

    return replace(scene, load_lidar=load)


def extra_columns(sweep) -> dict[str, np.ndarray]:
    """Per-point arrays of a sweep other than xyz (intensity, ...) that must follow a point selection."""
    from dataclasses import fields

    n = len(sweep.xyz_ego)
    return {f.name: getattr(sweep, f.name) for f in fields(sweep)
            if f.name != "xyz_ego" and isinstance(getattr(sweep, f.name), np.ndarray)
            and len(getattr(sweep, f.name)) == n}
