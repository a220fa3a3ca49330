"""nuav2.geometry: round trips, independent oracles (scipy) and the numerical hard cases."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation, Slerp

from nuav2.geometry import (
    T_from_quat_trans,
    T_inverse,
    T_to_quat_trans,
    egoS_T_egoT_from_heights,
    interpolate_poses,
    make_T,
    quat_multiply,
    quat_normalize,
    quat_slerp,
    quat_to_rot,
    rot_to_quat,
    transform_points,
    translation_T,
    yaw_of,
)

finite = st.floats(-1.0, 1.0, allow_nan=False, allow_infinity=False)
quats = st.tuples(finite, finite, finite, finite).filter(lambda q: np.linalg.norm(q) > 0.1).map(np.array)
trans = st.tuples(*[st.floats(-1e4, 1e4, allow_nan=False)] * 3).map(np.array)


def same_rotation(q_a: np.ndarray, q_b: np.ndarray, atol: float = 1e-12) -> bool:
    """Quaternions q and -q are the same rotation."""
    return bool(np.allclose(q_a, q_b, atol=atol) or np.allclose(q_a, -q_b, atol=atol))


def to_scipy(q_wxyz: np.ndarray) -> Rotation:
    return Rotation.from_quat(np.roll(np.asarray(q_wxyz), -1, axis=-1))  # scipy is x, y, z, w


@settings(max_examples=200, deadline=None)
@given(quats)
def test_quat_rot_round_trip_and_scipy_oracle(q):
    R = quat_to_rot(q)
    assert np.allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.isclose(np.linalg.det(R), 1.0, atol=1e-12)
    assert np.allclose(R, to_scipy(q).as_matrix(), atol=1e-12)
    q_back = rot_to_quat(R)
    assert q_back[0] >= 0
    assert same_rotation(q_back, q / np.linalg.norm(q), atol=1e-10)


@pytest.mark.parametrize("axis", [(1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 0), (1, -1, 1)])
@pytest.mark.parametrize("angle", [0.0, 1e-9, np.pi / 2, np.pi - 1e-9, np.pi])
def test_rot_to_quat_every_branch(axis, angle):
    """Identity, tiny and 180-degree rotations exercise all four branches of Shepperd's method."""
    R = Rotation.from_rotvec(np.asarray(axis, float) / np.linalg.norm(axis) * angle).as_matrix()
    q = rot_to_quat(R)
    assert np.all(np.isfinite(q))
    assert np.isclose(np.linalg.norm(q), 1.0, atol=1e-14)
    assert np.allclose(quat_to_rot(q), R, atol=1e-12)


def test_rot_to_quat_keeps_batch_shape():
    R = Rotation.random(6, random_state=0).as_matrix().reshape(2, 3, 3, 3)
    q = rot_to_quat(R)
    assert q.shape == (2, 3, 4)
    assert np.allclose(quat_to_rot(q), R, atol=1e-12)


@pytest.mark.parametrize("bad", [[0, 0, 0, 0], [np.nan, 0, 0, 1], [np.inf, 0, 0, 0]])
def test_quat_normalize_rejects_degenerate(bad):
    with pytest.raises(ValueError, match="finite and non-zero"):
        quat_normalize(bad)


def test_quat_normalize_makes_w_nonnegative():
    assert np.allclose(quat_normalize([-2.0, 0.0, 0.0, 0.0]), [1, 0, 0, 0])
    assert quat_normalize([-0.5, 0.5, 0.5, 0.5])[0] > 0


@settings(max_examples=100, deadline=None)
@given(quats, quats)
def test_quat_multiply_is_rotation_composition(a, b):
    assert np.allclose(quat_to_rot(quat_multiply(a, b)), quat_to_rot(a) @ quat_to_rot(b), atol=1e-12)


@settings(max_examples=100, deadline=None)
@given(quats, trans, quats, trans, st.tuples(*[st.floats(-50, 50)] * 3).map(np.array))
def test_inverse_and_compose_round_trip(qa, ta, qb, tb, p):
    a_T_b = T_from_quat_trans(qa, ta)
    b_T_c = T_from_quat_trans(qb, tb)
    a_T_c = a_T_b @ b_T_c
    # a_T_c applied to a c-frame point equals the two steps; 1e4 m translations keep ~1e-9 relative error.
    scale = 1.0 + np.abs(ta).max() + np.abs(tb).max()
    two_steps = transform_points(a_T_b, transform_points(b_T_c, p[None]))
    assert np.allclose(transform_points(a_T_c, p[None]), two_steps, rtol=0, atol=1e-12 * scale)
    assert np.allclose(T_inverse(a_T_b) @ a_T_b, np.eye(4), rtol=0, atol=1e-12 * scale)
    assert np.allclose(T_inverse(a_T_c), T_inverse(b_T_c) @ T_inverse(a_T_b), rtol=0, atol=1e-12 * scale)
    q_back, t_back = T_to_quat_trans(a_T_b)
    assert same_rotation(q_back, qa / np.linalg.norm(qa), atol=1e-10)
    assert np.allclose(t_back, ta, rtol=0, atol=0)


def test_city_scale_round_trip_relative_precision():
    """A city-scale pose (1e4 m) maps points out and back with relative error below 1e-9."""
    rng = np.random.default_rng(0)
    for _ in range(20):
        city_T_ego = T_from_quat_trans(rng.normal(size=4), rng.uniform(-1e4, 1e4, 3))
        p_ego = rng.uniform(-100, 100, (50, 3))
        p_city = transform_points(city_T_ego, p_ego)
        p_back = transform_points(T_inverse(city_T_ego), p_city)
        assert np.max(np.abs(p_back - p_ego)) / 1e4 < 1e-9


def test_make_T_and_batch_inverse():
    R = Rotation.random(5, random_state=1).as_matrix()
    t = np.arange(15.0).reshape(5, 3)
    T = make_T(R, t)
    assert T.shape == (5, 4, 4)
    assert np.allclose(T[:, 3], [0, 0, 0, 1])
    assert np.allclose(T_inverse(T) @ T, np.broadcast_to(np.eye(4), (5, 4, 4)), atol=1e-12)
    assert np.allclose(T_inverse(T), np.linalg.inv(T), atol=1e-12)


def test_slerp_endpoints_midpoint_and_scipy_oracle():
    q0 = Rotation.from_euler("z", 10, degrees=True)
    q1 = Rotation.from_euler("xyz", [20, -30, 100], degrees=True)
    wxyz = [np.roll(r.as_quat(), 1) for r in (q0, q1)]
    assert same_rotation(quat_slerp(wxyz[0], wxyz[1], 0.0), quat_normalize(wxyz[0]))
    assert same_rotation(quat_slerp(wxyz[0], wxyz[1], 1.0), quat_normalize(wxyz[1]))
    mid = to_scipy(quat_slerp(wxyz[0], wxyz[1], 0.5))
    # The midpoint is equally far (in angle) from both ends, half the total angle.
    total = (q0.inv() * q1).magnitude()
    assert np.isclose((q0.inv() * mid).magnitude(), total / 2, atol=1e-12)
    assert np.isclose((mid.inv() * q1).magnitude(), total / 2, atol=1e-12)
    ts = np.linspace(0, 1, 11)
    oracle = Slerp([0, 1], Rotation.concatenate([q0, q1]))(ts)
    ours = quat_to_rot(quat_slerp(wxyz[0], wxyz[1], ts))
    assert np.allclose(ours, oracle.as_matrix(), atol=1e-12)


def test_slerp_takes_the_short_way_and_handles_tiny_angles():
    q0 = np.array([1.0, 0, 0, 0])
    q1 = np.roll(Rotation.from_euler("z", 170, degrees=True).as_quat(), 1)
    mid_a = quat_slerp(q0, q1, 0.5)
    mid_b = quat_slerp(q0, -q1, 0.5)  # -q1 is the same rotation: same answer
    assert same_rotation(mid_a, mid_b)
    assert np.isclose(abs(np.degrees(yaw_of(quat_to_rot(mid_a)))), 85.0, atol=1e-9)
    q_tiny = quat_normalize([1.0, 1e-13, 0, 0])
    out = quat_slerp(q0, q_tiny, np.linspace(0, 1, 5))
    assert np.all(np.isfinite(out))
    assert np.allclose(out, q0, atol=1e-12)
    assert np.allclose(quat_slerp(q0, q0, 0.3), q0)


def _pose_table():
    rng = np.random.default_rng(3)
    ts = np.array([0, 5_000_000, 9_000_000, 20_000_000], dtype=np.int64) + 315_973_157_899_927_214
    poses = T_from_quat_trans(rng.normal(size=(4, 4)), rng.uniform(-5e3, 5e3, (4, 3)))
    return ts, poses


def test_interpolate_poses_exact_at_table_timestamps():
    ts, poses = _pose_table()
    out = interpolate_poses(ts, poses, ts)
    assert np.allclose(out, poses, rtol=0, atol=1e-9)


def test_interpolate_poses_midpoint_is_lerp_and_slerp():
    ts, poses = _pose_table()
    mid = (ts[1] + ts[2]) // 2
    out = interpolate_poses(ts, poses, mid)[0]
    assert np.allclose(out[:3, 3], (poses[1, :3, 3] + poses[2, :3, 3]) / 2, rtol=0, atol=1e-9)
    q1, q2 = rot_to_quat(poses[1, :3, :3]), rot_to_quat(poses[2, :3, :3])
    assert np.allclose(out[:3, :3], quat_to_rot(quat_slerp(q1, q2, 0.5)), atol=1e-12)


def test_interpolate_poses_keeps_nanosecond_precision():
    """At ~3.16e17 ns a float64 timestamp steps by 64 ns; weights must come from int64 differences."""
    t0 = 315_973_157_899_927_214
    ts = np.array([t0, t0 + 2], dtype=np.int64)
    poses = np.stack([translation_T(1e4, 0, 0), translation_T(1e4 + 2.0, 0, 0)])
    out = interpolate_poses(ts, poses, np.array([t0 + 1], dtype=np.int64))
    assert out[0, 0, 3] == pytest.approx(1e4 + 1.0, abs=1e-9)


def test_interpolate_poses_out_of_range_and_extrapolation():
    ts, poses = _pose_table()
    with pytest.raises(ValueError, match="outside the pose table"):
        interpolate_poses(ts, poses, ts[0] - 1)
    with pytest.raises(ValueError, match="outside the pose table"):
        interpolate_poses(ts, poses, ts[-1] + 1)
    clamped = interpolate_poses(ts, poses, [ts[0] - 10, ts[-1] + 10], max_extrapolation_ns=10)
    assert np.allclose(clamped, poses[[0, -1]], atol=1e-9)


@pytest.mark.parametrize("case", ["duplicate", "decreasing", "nan", "shape"])
def test_interpolate_poses_rejects_bad_tables(case):
    ts, poses = _pose_table()
    if case == "duplicate":
        ts = ts.copy()
        ts[2] = ts[1]
    elif case == "decreasing":
        ts = ts[::-1].copy()
    elif case == "nan":
        poses = poses.copy()
        poses[1, 0, 3] = np.nan
    else:
        poses = poses[:3]
    with pytest.raises(ValueError):
        interpolate_poses(ts, poses, ts[0])


def test_single_pose_table():
    poses = translation_T(1, 2, 3)[None]
    assert np.allclose(interpolate_poses([7], poses, 7), poses)
    with pytest.raises(ValueError):
        interpolate_poses([7], poses, 8)


def test_ego_frame_alignment_by_origin_height():
    """A point h above the ground has z = h - origin_height in each vehicle frame (paper eq. 1)."""
    egoS_T_egoT = egoS_T_egoT_from_heights(0.32, 0.0)
    h = np.array([[3.0, -1.0, 1.5]])  # in the target (ground-level) frame z = h
    p_S = transform_points(egoS_T_egoT, h)
    assert np.allclose(p_S, [[3.0, -1.0, 1.5 - 0.32]], atol=1e-15)
    back = egoS_T_egoT_from_heights(0.0, 0.32)
    assert np.allclose(back @ egoS_T_egoT, np.eye(4), atol=1e-15)


def test_yaw_of():
    for deg in (-179.0, -90.0, 0.0, 45.0, 180.0):
        R = Rotation.from_euler("z", deg, degrees=True).as_matrix()
        assert np.isclose(np.cos(yaw_of(R) - np.radians(deg)), 1.0)
