"""Label noise: smoothed annotated tracks (both modes), learned per-frame box-pose corrections (render)."""

from __future__ import annotations

import math

import numpy as np
import torch

from nuav2.actor_tracks import smooth_box_poses
from nuav2.geometry import make_T
from nuav2.rig import CameraSpec
from nuav2.splat.losses import photometric_loss
from nuav2.splat.scene_model import GaussianSet, ObjectModel, SkyModel, SplatScene, TrackPoses

CAM_R_FORWARD_X = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def yaw_R(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def track(n: int = 30, accel: float = 1.0, yaw_rate: float = 0.3):
    ts = (np.arange(n) * 100_000_000).astype(np.int64)
    t = ts * 1e-9
    x, y = 5.0 * t + 0.5 * accel * t**2, 0.2 * t**2
    yaw = 0.1 + yaw_rate * t
    return ts, np.stack([make_T(yaw_R(a), [xi, yi, 0.8]) for a, xi, yi in zip(yaw, x, y)])


def jitter(T: np.ndarray, rng, sigma_m: float = 0.04, sigma_yaw: float = 0.005) -> np.ndarray:
    out = T.copy()
    for i in range(len(T)):
        out[i, :3, :3] = yaw_R(rng.normal(0, sigma_yaw)) @ T[i, :3, :3]
        out[i, :3, 3] += rng.normal(0, sigma_m, 3) * [1, 1, 0.3]
    return out


def test_smoothing_keeps_exact_motion_and_removes_jitter():
    ts, truth = track()
    np.testing.assert_allclose(smooth_box_poses(ts, truth), truth, atol=1e-9)  # quadratic motion: unchanged
    rng = np.random.default_rng(0)
    noisy = jitter(truth, rng)
    smooth = smooth_box_poses(ts, noisy)
    err_raw = np.linalg.norm(noisy[:, :3, 3] - truth[:, :3, 3], axis=1)
    err_smooth = np.linalg.norm(smooth[:, :3, 3] - truth[:, :3, 3], axis=1)
    assert err_smooth.mean() < 0.65 * err_raw.mean()
    yaw = lambda T: np.arctan2(T[:, 1, 0], T[:, 0, 0])  # noqa: E731
    assert np.abs(yaw(smooth) - yaw(truth)).mean() < 0.65 * np.abs(yaw(noisy) - yaw(truth)).mean()
    # rotations stay rotations
    np.testing.assert_allclose(np.einsum("nji,njk->nik", smooth[:, :3, :3], smooth[:, :3, :3]),
                               np.broadcast_to(np.eye(3), (len(ts), 3, 3)), atol=1e-12)


def test_a_parked_track_gets_one_pose():
    ts = (np.arange(40) * 100_000_000).astype(np.int64)
    truth = np.repeat(make_T(yaw_R(3.1), [10.0, -4.0, 0.9])[None], 40, axis=0)
    noisy = jitter(truth, np.random.default_rng(1), sigma_m=0.08, sigma_yaw=0.01)
    smooth = smooth_box_poses(ts, noisy)
    assert np.allclose(smooth, smooth[0])
    assert np.linalg.norm(smooth[0, :3, 3] - truth[0, :3, 3]) < 0.04  # the median of 40 jittered frames
    assert abs(math.remainder(math.atan2(smooth[0, 1, 0], smooth[0, 0, 0]) - 3.1, 2 * math.pi)) < 0.01


def test_pose_corrections_interpolate_and_bake_into_the_track():
    ts, T = track(n=5)
    tr = TrackPoses("a", "VEHICLE", np.array([4.0, 2.0, 1.5]), ts, T.copy())
    tr.pose_delta = torch.zeros(5, 4)
    tr.pose_delta[0, 0], tr.pose_delta[1, 0], tr.pose_delta[1, 3] = 0.1, 0.3, 0.02
    mid = (ts[0] + ts[1]) // 2
    np.testing.assert_allclose(tr.delta_at(mid).numpy(), [0.2, 0, 0, 0.01], atol=1e-6)
    np.testing.assert_allclose(tr.delta_at(ts[-1] + 10**9).numpy(), 0.0)  # held at the end
    pts = np.random.default_rng(2).normal(0, 0.5, (30, 3))
    g = GaussianSet.create(pts, np.full((30, 3), 0.5), np.full(30, 0.1))
    scene = SplatScene(np.eye(4), GaussianSet.empty(), [ObjectModel(tr, g)], SkyModel(8, 16))
    before = {t: scene.gather(int(t))[0]["means"].detach().clone() for t in ts}
    tr.bake_deltas()
    assert tr.pose_delta is None
    for t in ts:  # at the annotated times the baked poses place the Gaussians where the corrections did
        np.testing.assert_allclose(scene.gather(int(t))[0]["means"].numpy(), before[t].numpy(), atol=1e-5)


def test_learned_corrections_pull_jittered_boxes_back():
    """A textured object rendered at its true poses; training only the corrections, starting from jittered
    poses, brings the boxes back towards the truth (smoothness prior included)."""
    from nuav2.splat.pose_prior import pose_prior
    from nuav2.splat.train import TrainConfig

    rng = np.random.default_rng(3)
    K = np.array([[60.0, 0.0, 31.5], [0.0, 60.0, 23.5], [0.0, 0.0, 1.0]])
    cam = CameraSpec("CAM", 64, 48, K, np.eye(4))
    city_T_cam = make_T(CAM_R_FORWARD_X, [-8.0, 0.0, 0.8])
    n = 6
    ts = (np.arange(n) * 100_000_000).astype(np.int64)
    truth = np.stack([make_T(yaw_R(0.0), [0.1 * i, 0.0, 0.8]) for i in range(n)])
    noisy = truth.copy()
    noisy[:, 1, 3] += rng.choice([-1, 1], n) * 0.12  # sideways label jitter
    pts = rng.uniform(-1, 1, (400, 3)) * [2.0, 0.9, 0.7]
    pts[:, 0] = -2.0  # the face the camera sees (it looks along +x)
    rgb = np.stack([0.5 + 0.4 * np.sin(6 * pts[:, 1]), 0.5 + 0.4 * np.cos(5 * pts[:, 2]), np.full(400, 0.4)],
                   -1)
    g = GaussianSet.create(pts, rgb, np.full(400, 0.08), opacity=0.9, sh_degree=0)
    true_track = TrackPoses("a", "V", np.ones(3), ts, truth)
    true_scene = SplatScene(np.eye(4), GaussianSet.empty(0), [ObjectModel(true_track, g)], SkyModel(8, 16))
    with torch.no_grad():
        targets = [true_scene.render(cam, city_T_cam, int(t)).rgb for t in ts]
    tr = TrackPoses("a", "V", np.ones(3), ts, noisy.copy())
    tr.pose_delta = torch.zeros(n, 4, requires_grad=True)
    scene = SplatScene(np.eye(4), GaussianSet.empty(0), [ObjectModel(tr, g)], SkyModel(8, 16))
    cfg = TrainConfig()
    opt = torch.optim.Adam([tr.pose_delta], lr=5e-3)
    for it in range(150):
        k = it % n
        out = scene.render(cam, city_T_cam, int(ts[k]))
        loss = photometric_loss(out.rgb, targets[k], None, 0.2)[0]
        loss = loss + pose_prior(tr, cfg.lambda_pose, cfg.lambda_pose_smooth)
        opt.zero_grad()
        loss.backward()
        opt.step()
    tr.bake_deltas()
    before = np.abs(noisy[:, 1, 3] - truth[:, 1, 3]).mean()
    after = np.abs(tr.scene_T_box[:, 1, 3] - truth[:, 1, 3]).mean()
    assert after < 0.5 * before, (before, after)


def test_non_rigid_actors_become_time_segments_that_tile_their_presence():
    from nuav2.splat.actors import object_tracks, segment_track
    from nuav2.splat.init import InitConfig

    ts, T = track(n=20)  # 1.9 s, moving
    walker = TrackPoses("p", "PEDESTRIAN", np.array([0.6, 0.6, 1.7]), ts, T)
    car = TrackPoses("c", "REGULAR_VEHICLE", np.array([4.5, 1.9, 1.6]), ts, T)
    parked = TrackPoses("q", "PEDESTRIAN", np.array([0.6, 0.6, 1.7]), ts, np.repeat(T[:1], 20, axis=0))
    objs = object_tracks([walker, car, parked], InitConfig(nonrigid_segment_s=0.2))
    keys = [o.key for o in objs]
    assert "c" in keys and not any(k.startswith("q") for k in keys)  # a standing pedestrian stays background
    segs = [o for o in objs if o.track_id == "p"]
    assert len(segs) == len(segment_track(walker, 200_000_000)) >= 9 and keys.count("c") == 1
    # Every time of the walker's presence belongs to exactly one segment; outside it, to none.
    lo, hi = int(ts[0]) - walker.presence_margin_ns, int(ts[-1]) + walker.presence_margin_ns
    for t in np.linspace(lo, hi, 97).astype(np.int64):
        assert sum(s.present(int(t)) for s in segs) == 1
    assert not any(s.present(lo - 1) or s.present(hi + 1) for s in segs)
    # Rigid when segmenting is off.
    assert [o.key for o in object_tracks([walker], InitConfig(nonrigid_segment_s=0.0))] == ["p"]
