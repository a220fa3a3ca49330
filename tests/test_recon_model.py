"""Scene model: Gaussian containers, object placement along tracks, sky lookup, rendering conventions."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from nuav2.geometry import T_from_quat_trans, make_T, quat_multiply, quat_to_rot, rot_to_quat, translation_T
from nuav2.rig import CameraSpec
from nuav2.splat.scene_model import (
    GaussianSet,
    ObjectModel,
    SkyModel,
    SplatScene,
    TrackPoses,
    pixel_rays,
    scene_frame_for,
)
from nuav2.splat.visible import quat_mul_torch

# OpenCV camera looking along +x of a z-up world (x right = -y world, y down = -z world, z fwd = +x world).
CAM_R_FORWARD_X = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def small_camera(w: int = 48, h: int = 32, f: float = 40.0) -> CameraSpec:
    K = np.array([[f, 0.0, (w - 1) / 2], [0.0, f, (h - 1) / 2], [0.0, 0.0, 1.0]])
    return CameraSpec("CAM", w, h, K, np.eye(4))


def yaw_R(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def empty_scene(city_T_scene: np.ndarray | None = None) -> SplatScene:
    frame = np.eye(4) if city_T_scene is None else city_T_scene
    return SplatScene(frame, GaussianSet.empty(), [], SkyModel(8, 16))


def test_quat_mul_torch_matches_geometry():
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(20, 4)), rng.normal(size=(20, 4))
    ours = quat_mul_torch(torch.tensor(a), torch.tensor(b)).numpy()
    np.testing.assert_allclose(ours, quat_multiply(a, b), atol=1e-12)


def test_create_colour_roundtrip_through_sh_dc():
    rgb = np.array([[0.1, 0.5, 0.9], [1.0, 0.0, 0.25]])
    g = GaussianSet.create(np.zeros((2, 3)), rgb, np.full(2, 0.1), opacity=0.4, sh_degree=2)
    assert g.sh.shape == (2, 9, 3) and g.sh_degree == 2
    np.testing.assert_allclose((0.28209479177387814 * g.sh[:, 0] + 0.5).numpy(), rgb, atol=1e-6)
    np.testing.assert_allclose(g.opacities().numpy(), 0.4, atol=1e-6)
    np.testing.assert_allclose(torch.exp(g.log_scales).numpy(), 0.1, rtol=1e-6)


def test_set_shape_errors_and_select_concat():
    with pytest.raises(ValueError, match="quats"):
        GaussianSet(torch.zeros(3, 3), torch.zeros(2, 4), torch.zeros(3, 3), torch.zeros(3),
                    torch.zeros(3, 1, 3))
    g = GaussianSet.create(np.arange(12.0).reshape(4, 3), np.full((4, 3), 0.5), np.full(4, 0.2))
    sub = g.select(torch.tensor([True, False, True, False]))
    both = sub.concat(g)
    assert len(sub) == 2 and len(both) == 6
    np.testing.assert_allclose(both.means[:2].numpy(), g.means[[0, 2]].numpy())


def test_track_interpolation_and_presence():
    ts = np.array([0, 100_000_000, 200_000_000], np.int64)
    poses = np.stack([translation_T(x=10.0 * i) for i in range(3)])
    tr = TrackPoses("t", "REGULAR_VEHICLE", np.array([4.0, 2.0, 1.5]), ts, poses)
    np.testing.assert_allclose(tr.scene_T_box_at(150_000_000)[:3, 3], [15.0, 0, 0], atol=1e-9)
    assert tr.present(-40_000_000) and tr.present(240_000_000)
    assert not tr.present(-60_000_000) and not tr.present(260_000_000)
    np.testing.assert_allclose(tr.scene_T_box_at(240_000_000)[:3, 3], [20.0, 0, 0], atol=1e-9)


def test_gather_places_objects_in_box_frame():
    """Object means and rotations compose with the box pose: oracle with float64 geometry."""
    rng = np.random.default_rng(1)
    q_box = rng.normal(size=4)
    box_T = T_from_quat_trans(q_box, [3.0, -2.0, 0.5])
    tr = TrackPoses("car", "REGULAR_VEHICLE", np.array([4.0, 2.0, 1.5]), np.array([0, 10], np.int64),
                    np.stack([box_T, box_T]))
    pts = rng.normal(size=(5, 3))
    q_local = rng.normal(size=(5, 4))
    g = GaussianSet.create(pts, np.full((5, 3), 0.5), np.full(5, 0.1), quats=q_local)
    scene = empty_scene()
    scene.objects.append(ObjectModel(tr, g))
    gathered, slices = scene.gather(5)
    sl = slices["car"]
    np.testing.assert_allclose(gathered["means"][sl].numpy(), pts @ box_T[:3, :3].T + box_T[:3, 3], atol=1e-5)
    R_expect = box_T[:3, :3] @ quat_to_rot(q_local)
    np.testing.assert_allclose(quat_to_rot(gathered["quats"][sl].double().numpy()), R_expect, atol=1e-5)
    # Outside the track's span the object is absent.
    far, slices_far = scene.gather(10**12)
    assert "car" not in slices_far and len(far["means"]) == 0


def test_gather_gradients_reach_object_parameters():
    tr = TrackPoses("car", "X", np.ones(3), np.array([0], np.int64), translation_T(x=5.0)[None])
    g = GaussianSet.create(np.zeros((3, 3)), np.full((3, 3), 0.5), np.full(3, 0.1)).requires_grad_(True)
    scene = empty_scene()
    scene.objects.append(ObjectModel(tr, g))
    gathered, _ = scene.gather(0)
    gathered["means"].sum().backward()
    np.testing.assert_allclose(g.means.grad.numpy(), 1.0)


def test_sky_lookup_follows_world_direction_not_camera():
    """A bright texel at azimuth 90 deg (north) is seen where the camera looks north, whatever its yaw."""
    sky = SkyModel(16, 64)
    with torch.no_grad():
        sky.texture.fill_(-4.0)
        col = 48  # column centre azimuth = -pi + 2 pi * 48 / 64 = pi / 2
        sky.texture[:, :, col] = 4.0
        north = sky(torch.tensor([[0.0, 1.0, 0.1]]))
        east = sky(torch.tensor([[1.0, 0.0, 0.1]]))
    assert float(north.min()) > 0.95 and float(east.max()) < 0.05
    cam = small_camera(49, 33)
    centre = (cam.height // 2, cam.width // 2)
    for yaw in (0.0, 0.7, math.pi / 2, -2.5):
        scene_T_cam = make_T(yaw_R(yaw) @ CAM_R_FORWARD_X, [0, 0, 0])
        d = pixel_rays(cam, scene_T_cam)[centre]
        np.testing.assert_allclose(math.atan2(float(d[1]), float(d[0])), yaw, atol=1e-5)
        expect_bright = abs(math.remainder(yaw - math.pi / 2, 2 * math.pi)) < 1e-6
        v = float(sky(d[None]).detach().min())
        assert (v > 0.95) == expect_bright


def test_sky_wraps_at_azimuth_pi():
    sky = SkyModel(8, 32)
    with torch.no_grad():
        sky.texture.normal_()
    eps = 1e-5
    a = sky(torch.tensor([[math.cos(math.pi - eps), math.sin(math.pi - eps), 0.2]]))
    b = sky(torch.tensor([[math.cos(-math.pi + eps), math.sin(-math.pi + eps), 0.2]]))
    np.testing.assert_allclose(a.detach().numpy(), b.detach().numpy(), atol=1e-3)
    low = sky(torch.tensor([[1.0, 0.0, -5.0]]))  # below the texture's range: clamps, stays finite
    assert torch.isfinite(low).all()


def test_render_pixel_convention_matches_rig():
    """A small Gaussian on the ray of pixel (u, v) (centre of pixel u is u) peaks at that pixel."""
    cam = small_camera()
    city_T_scene = translation_T(4000.0, 3000.0, 40.0)
    city_T_cam = city_T_scene @ make_T(CAM_R_FORWARD_X, [0, 0, 1.5])
    u, v = 31.0, 9.0
    K = cam.K
    ray_cam = np.array([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], 1.0]) * 10.0
    p_city = city_T_cam[:3, :3] @ ray_cam + city_T_cam[:3, 3]
    p_scene = p_city - city_T_scene[:3, 3]
    g = GaussianSet.create(p_scene[None], np.array([[1.0, 1.0, 1.0]]), np.array([0.05]), opacity=0.99,
                           sh_degree=0)
    scene = SplatScene(city_T_scene, g, [], SkyModel(4, 8))
    out = scene.render(cam, city_T_cam, 0, with_sky=False)
    r, c = np.unravel_index(int(out.alpha.argmax()), out.alpha.shape)
    assert (r, c) == (int(v), int(u))
    np.testing.assert_allclose(float(out.depth[r, c]), 10.0, rtol=1e-3)


def test_render_empty_scene_is_sky_only():
    scene = empty_scene(translation_T(5000.0, 1000.0, 30.0))
    cam = small_camera()
    out = scene.render(cam, translation_T(5000.0, 1000.0, 31.5) @ make_T(CAM_R_FORWARD_X, [0, 0, 0]), 0)
    assert out.rgb.shape == (cam.height, cam.width, 3) and torch.isfinite(out.rgb).all()
    assert float(out.alpha.max()) == 0.0


def test_save_load_roundtrip(tmp_path):
    rng = np.random.default_rng(2)
    g = GaussianSet.create(rng.normal(size=(50, 3)) + [0, 0, 10], rng.uniform(size=(50, 3)),
                           rng.uniform(0.05, 0.3, 50), opacity=0.6)
    tr = TrackPoses("car", "REGULAR_VEHICLE", np.array([4.0, 2.0, 1.5]), np.array([0, 10], np.int64),
                    np.stack([translation_T(y=3.0), translation_T(y=4.0)]))
    og = GaussianSet.create(rng.normal(size=(10, 3)), rng.uniform(size=(10, 3)), np.full(10, 0.2))
    scene = SplatScene(scene_frame_for(translation_T(3000.0, 2000.0, 12.0)), g, [ObjectModel(tr, og)],
                       SkyModel(8, 16), info={"note": "x"})
    path = tmp_path / "scene.pt"
    scene.save(path)
    back = SplatScene.load(path)
    cam = small_camera()
    city_T_cam = scene.city_T_scene @ make_T(CAM_R_FORWARD_X.T @ CAM_R_FORWARD_X @ CAM_R_FORWARD_X, [0, 0, 0])
    a = scene.render(cam, city_T_cam, 5).rgb
    b = back.render(cam, city_T_cam, 5).rgb
    assert torch.equal(a, b) and back.info == {"note": "x"}
    np.testing.assert_array_equal(back.objects[0].track.scene_T_box, tr.scene_T_box)
    (tmp_path / "bad.pt").write_bytes(b"not a scene")
    with pytest.raises(ValueError, match="bad.pt"):
        SplatScene.load(tmp_path / "bad.pt")


def test_scene_frame_is_translation_to_first_pose():
    city_T_ego = make_T(yaw_R(0.3), [5468.7, 2907.5, 40.57])
    f = scene_frame_for(city_T_ego)
    np.testing.assert_array_equal(f[:3, :3], np.eye(3))
    np.testing.assert_array_equal(f[:3, 3], city_T_ego[:3, 3])
    assert rot_to_quat(f[:3, :3])[0] == 1.0
