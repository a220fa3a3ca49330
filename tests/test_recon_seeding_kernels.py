"""The compiled and cell-wise shortcuts seeding takes on long logs give what the plain numpy forms give:
projection into a source image, distance bands from the ego path, and box poses read from a track's
memoised pose table (also after the learned corrections are baked in)."""

from __future__ import annotations

import numpy as np
import torch

from nuav2.geometry import T_from_quat_trans, interpolate_poses, make_T
from nuav2.rig import CameraSpec
from nuav2.splat.lidar_seeds import distance_bands, distance_to_path
from nuav2.splat.scene_model import TrackPoses
from nuav2.splat.views import project


def _rotation(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    return T_from_quat_trans(q / np.linalg.norm(q), rng.normal(size=3))


def test_projection_matches_the_numpy_form_and_drops_nan_points():
    rng = np.random.default_rng(0)
    pts = rng.uniform(-60, 60, (50_000, 3))
    pts[::37] = np.nan
    pts[5] = [0.0, 0.0, 0.1]  # exactly at the near plane: not in front
    K = np.array([[210.5, 0, 127.3], [0, 209.8, 96.1], [0, 0, 1.0]])
    cam = CameraSpec("CAM", 256, 194, K, np.eye(4))
    for T in (np.eye(4), _rotation(rng), _rotation(rng)):
        got = project(pts, cam, T)
        with np.errstate(invalid="ignore"):
            p = pts @ T[:3, :3].T + T[:3, 3]
            front = np.flatnonzero(p[:, 2] > 0.1)
        u = K[0, 0] * p[front, 0] / p[front, 2] + K[0, 2]
        v = K[1, 1] * p[front, 1] / p[front, 2] + K[1, 2]
        inside = (u > -0.5) & (u < 255.5) & (v > -0.5) & (v < 193.5)
        assert len(got.idx) > 1000
        np.testing.assert_array_equal(got.idx, front[inside])
        np.testing.assert_allclose(got.u, u[inside], rtol=0, atol=1e-9)
        np.testing.assert_allclose(got.v, v[inside], rtol=0, atol=1e-9)
        np.testing.assert_allclose(got.z, p[front[inside], 2], rtol=0, atol=1e-9)
        assert not np.isin(np.arange(0, len(pts), 37), got.idx).any()
    assert len(project(np.zeros((0, 3)), cam, np.eye(4)).idx) == 0


def test_distance_bands_equal_the_bands_of_each_points_own_distance():
    rng = np.random.default_rng(1)
    s = np.linspace(0, 1, 150)
    path = np.stack([120 * s, 15 * np.sin(3 * s)], 1)  # a curved 15 s drive
    pts = rng.uniform([-100, -100], [220, 100], (200_000, 2))
    # points right at the band edges, where a cell straddles one
    ang = rng.uniform(0, 2 * np.pi, 4000)
    for edge in (20.0, 40.0, 80.0):
        pts = np.concatenate([pts, path[0] + (edge + rng.uniform(-1e-6, 1e-6, 4000))[:, None]
                              * np.stack([np.cos(ang), np.sin(ang)], 1)])
    edges = (20.0, 40.0, 80.0)
    want = np.searchsorted(edges, distance_to_path(pts, path), side="right")
    for cell in (0.5, 1.0, 3.0):
        np.testing.assert_array_equal(distance_bands(pts, path, edges, cell_m=cell), want)
    assert set(np.unique(want)) == {0, 1, 2, 3}
    assert len(distance_bands(np.zeros((0, 2)), path, edges)) == 0


def _track() -> TrackPoses:
    ts = np.arange(10, dtype=np.int64) * 100_000_000
    yaw = np.linspace(0, 0.8, 10)
    R = np.stack([np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]]) for a in yaw])
    poses = make_T(R, np.stack([np.linspace(0, 9, 10), np.linspace(0, 2, 10), np.zeros(10)], 1))
    return TrackPoses("t1", "REGULAR_VEHICLE", np.array([4.0, 2.0, 1.5]), ts, poses)


def test_track_pose_table_prefetch_and_bake_give_the_interpolated_poses():
    track = _track()
    query = [0, 150_000_000, 333_333_333, 900_000_000, 930_000_000]  # the last one within the margin
    want = interpolate_poses(track.timestamps_ns, track.scene_T_box, query, track.presence_margin_ns)
    track.prefetch(query + [5_000_000_000])  # absent times are skipped, not an error
    for t, w in zip(query, want):
        got = track.scene_T_box_at(t)
        np.testing.assert_array_equal(got, w)
        got[:] = 0  # a caller's copy: the table is not changed
        np.testing.assert_array_equal(track.scene_T_box_at(t), w)
    track.pose_delta = torch.zeros(10, 4)
    track.pose_delta[:, 0] = 0.5  # half a metre forward in the box frame
    track.bake_deltas()  # replaces scene_T_box: the table must follow
    moved = track.scene_T_box_at(900_000_000)  # an annotated time
    np.testing.assert_allclose(moved[:3, 3] - want[3][:3, 3], 0.5 * want[3][:3, 0], atol=1e-12)
