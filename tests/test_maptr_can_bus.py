"""CAN bus [7:16] of the MapTRv2 infos: acceleration (as an accelerometer reads it), rotation rate and
velocity in the ego frame, from neighbouring LIDAR_TOP ego poses, as nuScenes' CAN pose messages give
them to MapTR's ``can_bus_mlp``.

Oracles: hand-built constant-rate circular motion, constant acceleration and a tilted car at rest
(closed forms), scipy's rotation vectors, and, end to end, the synthetic world's own trajectory
behind a log that ``nuav2 convert`` turned into a database (a curved road: the ego turns).
"""

from __future__ import annotations

import math
import pickle
from pathlib import Path

import numpy as np
import pytest
from e2e_helpers import VERSION, cli
from scipy.spatial.transform import Rotation

from nuav2.ego_motion import GRAVITY_MPS2, ego_motion, rotation_vector
from nuav2.maptr.infos import can_bus_from_pose, info_filename

pytest_plugins = ["test_maptr_infos_support"]

G = np.array([0.0, 0.0, GRAVITY_MPS2])


def _T(R: np.ndarray, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def _circle(v: float, w: float, times: np.ndarray, psi0: float = 0.7, p0=(512.0, -80.0, 3.0)) -> np.ndarray:
    """global_T_ego of a level car driving a circle at speed v and yaw rate w (left turn for w > 0)."""
    psi = psi0 + w * times
    x = p0[0] + v / w * (np.sin(psi) - np.sin(psi0))
    y = p0[1] - v / w * (np.cos(psi) - np.cos(psi0))
    rot = Rotation.from_euler("z", psi[:, None]).as_matrix()
    return np.array([_T(R, (xi, yi, p0[2])) for R, xi, yi in zip(rot, x, y)])


# ------------------------------------------------------------------ the pure function


def test_circular_motion_gives_speed_yaw_rate_and_centripetal_acceleration_on_plus_y():
    v, w, dt = 10.0, 0.3, 0.1
    times = np.arange(7) * dt + 1234.5
    poses = _circle(v, w, times)
    for k in range(1, 6):  # central differences
        m = ego_motion(times, poses, k)
        accel, rate, vel = m[0:3], m[3:6], m[6:9]
        np.testing.assert_allclose(vel, [v, 0.0, 0.0], rtol=0, atol=v * (w * dt) ** 2 / 6 * 1.01)
        np.testing.assert_allclose(rate, [0.0, 0.0, w], rtol=0, atol=1e-12)
        np.testing.assert_allclose(accel, [0.0, v * w, GRAVITY_MPS2], rtol=0,
                                   atol=v * w * (w * dt) ** 2 / 12 * 1.01)
    for k in (0, 6):  # one-sided at the ends: first-order, the chord turned by w dt / 2
        m = ego_motion(times, poses, k)
        assert m[6] == pytest.approx(v, rel=1e-3)
        assert abs(m[7]) == pytest.approx(v * math.sin(w * dt / 2), rel=1e-3)
        assert m[5] == pytest.approx(w, abs=1e-12)
        assert m[1] == pytest.approx(v * w, rel=2 * w * dt) and m[2] == pytest.approx(GRAVITY_MPS2)


def test_a_right_turn_has_negative_yaw_rate_and_acceleration_to_the_right():
    times = np.arange(3) * 0.1
    m = ego_motion(times, _circle(8.0, -0.2, times), 1)
    assert m[5] < 0 and m[1] < 0 and m[6] > 0


def test_uneven_sweep_times_keep_central_differences_accurate():
    v, w = 10.0, 0.3
    times = np.array([0.0, 0.1004, 0.1998, 0.3001])
    poses = _circle(v, w, times)
    m = ego_motion(times, poses, 1)
    np.testing.assert_allclose(m[6:9], [v, 0, 0], atol=2e-3)
    np.testing.assert_allclose(m[3:6], [0, 0, w], atol=1e-12)
    np.testing.assert_allclose(m[0:3], [0, v * w, GRAVITY_MPS2], atol=0.01)


def test_constant_acceleration_on_a_straight_line_is_exact():
    a, v0 = 1.5, 4.0
    times = np.arange(5) * 0.1
    R = Rotation.from_euler("z", -2.0).as_matrix()
    poses = np.array([_T(R, R @ [v0 * t + 0.5 * a * t * t, 0, 0] + [10, 20, 1]) for t in times])
    for k in range(5):
        m = ego_motion(times, poses, k)
        np.testing.assert_allclose(m[0:3], [a, 0, GRAVITY_MPS2], atol=1e-9)
        np.testing.assert_allclose(m[3:6], 0, atol=1e-12)
    np.testing.assert_allclose(ego_motion(times, poses, 2)[6:9], [v0 + a * 0.2, 0, 0], atol=1e-9)


def test_a_tilted_car_at_rest_reads_gravity_only():
    R = Rotation.from_euler("ZYX", [1.1, -0.08, 0.03]).as_matrix()  # yaw, pitch nose up, roll
    poses = np.array([_T(R, (5.0, 6.0, 7.0))] * 4)
    m = ego_motion([0.0, 0.1, 0.2, 0.3], poses, 1)
    np.testing.assert_allclose(m[0:3], R.T @ G, atol=1e-12)
    assert np.linalg.norm(m[0:3]) == pytest.approx(GRAVITY_MPS2)
    assert m[0] > 0  # nose up: gravity's reading leans forward, as nuScenes' accel does uphill
    np.testing.assert_allclose(m[3:], 0, atol=1e-12)


def test_one_pose_gives_zeros_but_gravity_and_two_give_one_sided_velocity():
    R = Rotation.from_euler("z", 0.4).as_matrix()
    one = ego_motion([3.0], np.array([_T(R, (1, 2, 3))]), 0)
    np.testing.assert_allclose(one, [*(R.T @ G), 0, 0, 0, 0, 0, 0], atol=1e-12)
    two = np.array([_T(R, (1, 2, 3)), _T(R, R @ [0.8, 0, 0] + [1, 2, 3])])
    for k in (0, 1):
        m = ego_motion([3.0, 3.1], two, k)
        np.testing.assert_allclose(m, [0, 0, GRAVITY_MPS2, 0, 0, 0, 8.0, 0, 0], atol=1e-9)


def test_rotation_vector_is_the_log_map():
    rng = np.random.default_rng(0)
    small, large = rng.normal(size=(20, 3)) * 0.02, rng.normal(size=(20, 3)) * 1.2
    rots = Rotation.from_rotvec(np.concatenate([small, large, [[0, 0, 3.1], [1e-9, 0, 0]]]))
    for r in rots:
        np.testing.assert_allclose(rotation_vector(r.as_matrix()), r.as_rotvec(), atol=1e-9)
    np.testing.assert_array_equal(rotation_vector(np.eye(3)), np.zeros(3))


def test_can_bus_layout_puts_motion_in_7_to_16():
    q = [math.cos(0.3), 0.0, 0.0, math.sin(0.3)]  # yaw 0.6 rad
    motion = np.arange(9.0) + 1
    cb = can_bus_from_pose([1.0, 2.0, 3.0], q, motion)
    np.testing.assert_array_equal(cb[:3], [1, 2, 3])
    np.testing.assert_allclose(cb[3:7], q)
    np.testing.assert_array_equal(cb[7:16], motion)
    assert cb[16] == pytest.approx(0.6) and cb[17] == pytest.approx(math.degrees(0.6))
    np.testing.assert_array_equal(can_bus_from_pose([1.0, 2.0, 3.0], q)[7:16], 0)


# ------------------------------------------------------------------ end to end on a converted log


@pytest.fixture(scope="module")
def curved_infos(curved_db: Path, tmp_path_factory) -> list[dict]:
    out = tmp_path_factory.mktemp("can_bus_infos")
    code, _, err = cli("infos", curved_db, "--version", VERSION, "--out", out, "--splits", "all",
                       "--no-progress")
    assert code == 0, err
    return pickle.loads((out / info_filename("nuav2", "all")).read_bytes())["infos"]


def _world_truth(world, timestamp_us: int, h_s: float = 0.05) -> tuple[np.ndarray, float, np.ndarray]:
    """(velocity and acceleration in the ego frame, yaw rate) of the synthetic world's own trajectory
    (not the database), by central differences over +-h_s: the world's ego path is a polyline tabulated
    at 100 Hz, so its curvature is lumpy at finer steps."""
    ns, h = timestamp_us * 1000, int(h_s * 1e9)
    before, now, after = (world.city_T_ego_at(t) for t in (ns - h, ns, ns + h))
    ego_R_city = now[:3, :3].T
    vel = ego_R_city @ (after[:3, 3] - before[:3, 3]) / (2 * h_s)
    accel = ego_R_city @ (after[:3, 3] - 2 * now[:3, 3] + before[:3, 3]) / h_s**2
    yaw = [math.atan2(T[1, 0], T[0, 0]) for T in (before, after)]
    return vel, (yaw[1] - yaw[0]) / (2 * h_s), accel


def test_can_bus_motion_matches_the_synthetic_worlds_trajectory(curved_infos, curved_log: Path):
    from nuav2.synth import load_world

    world = load_world(curved_log)
    assert len(curved_infos) >= 5
    rates = []
    for k, info in enumerate(curved_infos):
        cb = info["can_bus"]
        assert cb.shape == (18,) and np.all(np.isfinite(cb))
        accel, rate, vel = cb[7:10], cb[10:13], cb[13:16]
        true_vel, true_rate, true_accel = _world_truth(world, info["timestamp"])
        interior = 0 < k < len(curved_infos) - 1
        # Velocity in m/s in the ego frame: forward speed ~9 m/s; at the ends the one-sided chord
        # is turned by |w| dt / 2 (~0.04 m/s sideways here).
        assert vel[0] == pytest.approx(true_vel[0], abs=0.01)
        np.testing.assert_allclose(vel, true_vel, atol=0.01 if interior else 0.05)
        # Rotation rate in rad/s about ego z, the sign of the turn.
        assert np.sign(rate[2]) == np.sign(true_rate) and abs(true_rate) > 0.02
        assert rate[2] == pytest.approx(true_rate, abs=0.005 if interior else 0.01)
        np.testing.assert_allclose(rate[:2], 0, atol=1e-9)  # flat ground: no pitch or roll rate
        # Accelerometer reading: gravity on +z (level car), centripetal towards the turn's inside.
        assert accel[2] == pytest.approx(GRAVITY_MPS2, abs=1e-6)
        assert np.sign(accel[1]) == np.sign(rate[2])
        if interior:
            np.testing.assert_allclose(accel[:2], true_accel[:2], atol=0.03)
        rates.append(rate[2])
    assert np.all(np.sign(rates) == np.sign(rates[0]))


def test_can_bus_pose_fields_are_what_maptr_overwrites(curved_infos):
    """[0:3], [3:7], [-2], [-1] hold the LIDAR_TOP ego pose and yaw (MapTR's dataset rewrites them)."""
    from pyquaternion import Quaternion

    for info in curved_infos:
        cb = info["can_bus"]
        np.testing.assert_allclose(cb[:3], info["ego2global_translation"])
        np.testing.assert_allclose(cb[3:7], info["ego2global_rotation"])
        yaw = Quaternion(info["ego2global_rotation"]).yaw_pitch_roll[0]
        assert cb[-1] == pytest.approx(np.degrees(yaw) % 360.0) and 0 <= cb[-2] < 2 * np.pi
        assert cb[-2] == pytest.approx(np.radians(cb[-1]))


def test_can_bus_expansion_serves_the_devkits_api_with_the_infos_values(curved_db: Path, curved_infos):
    """``convert`` writes ``can_bus/scene-NNNN_pose.json``: the devkit's NuScenesCanBus (which BEVFormer's
    and MapTR's stock converters open first) reads it, one message per LIDAR_TOP sweep, holding the ego
    pose and the motion ``nuav2 infos`` puts into can_bus[7:16]."""
    import json

    from nuscenes.can_bus.can_bus_api import NuScenesCanBus

    can = NuScenesCanBus(dataroot=str(curved_db))
    v = curved_db / VERSION
    scenes = {s["token"]: s["name"] for s in json.loads((v / "scene.json").read_text())}
    sample_data = json.loads((v / "sample_data.json").read_text())
    lidar_sweeps = [sd for sd in sample_data if sd["fileformat"] == "pcd"]
    by_scene = {name: can.get_messages(name, "pose") for name in scenes.values()}
    assert sum(len(m) for m in by_scene.values()) == len(lidar_sweeps)
    for messages in by_scene.values():
        assert [m["utime"] for m in messages] == sorted({m["utime"] for m in messages})
        assert list(messages[0]) == ["accel", "orientation", "pos", "rotation_rate", "utime", "vel"]
    for info in curved_infos:
        at = {m["utime"]: m for m in by_scene[scenes[info["scene_token"]]]}[info["timestamp"]]
        np.testing.assert_allclose(at["pos"], info["ego2global_translation"], rtol=0, atol=1e-9)
        assert at["orientation"] == list(info["ego2global_rotation"])
        np.testing.assert_allclose(at["accel"] + at["rotation_rate"] + at["vel"], info["can_bus"][7:16],
                                   rtol=0, atol=1e-9)
