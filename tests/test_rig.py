"""nuav2.rig: the built-in rigs, reference values, scaling/height round trips and strict validation."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import pytest

from nuav2.geometry import T_from_quat_trans, T_inverse, transform_points
from nuav2.rig import RIG_SPEC_DIR, CameraSpec, RigSpecError, available_rigs, load_rig, rig_from_dict

# nuScenes v1.0-mini scene-0061 calibration (reference/nuscenes_format.md section 9).
NUSCENES_REF = {
    "CAM_FRONT": (1266.417203046554, 816.2670197447984, 491.50706579294757,
                  [1.70079118954, 0.0159456324149, 1.51095763913],
                  [0.4998015430569128, -0.5030316162024876, 0.4997798114386805, -0.49737083824542755]),
    "CAM_FRONT_RIGHT": (1260.8474446004698, 807.968244525554, 495.3344268742088,
                        [1.5508477543, -0.493404796419, 1.49574800619],
                        [0.2060347966337182, -0.2026940577919598, 0.6824507824531167, -0.6713610884174485]),
    "CAM_FRONT_LEFT": (1272.5979470598488, 826.6154927353808, 479.75165386361925,
                       [1.52387798135, 0.494631336551, 1.50932822144],
                       [0.6757265034669446, -0.6736266522251881, 0.21214015046209478, -0.21122827103904068]),
    "CAM_BACK": (809.2209905677063, 829.2196003259838, 481.77842384512485,
                 [0.0283260309358, 0.00345136761476, 1.57910346144],
                 [0.5037872666382278, -0.49740249788611096, -0.4941850223835201, 0.5045496097725578]),
    "CAM_BACK_LEFT": (1256.7414812095406, 792.1125740759628, 492.7757465151356,
                      [1.03569100218, 0.484795032713, 1.59097014818],
                      [0.6924185592174665, -0.7031619420114925, -0.11648342771943819, 0.11203317912370753]),
    "CAM_BACK_RIGHT": (1259.5137405846733, 807.2529053838625, 501.19579884916527,
                       [1.0148780988, -0.480568219723, 1.56239545128],
                       [0.12280980120078765, -0.132400842670559, -0.7004305821388234, 0.690496031265798]),
}
NUSCENES_LIDAR_TOP = ([0.943713, 0.0, 1.84023],
                      [0.7077955119163518, -0.006492242056004365, 0.010646214713995808, -0.7063073142877817])


def project(cam: CameraSpec, p_ego: np.ndarray) -> np.ndarray:
    """Pixel (u, v) of ego-frame points, pixel centres at integer coordinates."""
    p_cam = transform_points(T_inverse(cam.ego_T_cam), p_ego)
    uvw = p_cam @ cam.K.T
    return uvw[:, :2] / uvw[:, 2:3]


def test_builtin_rigs_load():
    assert {"nuscenes", "av2", "truck5"} <= set(available_rigs())
    counts = {"nuscenes": 6, "av2": 9, "truck5": 5}
    for name, n_cams in counts.items():
        rig = load_rig(name)
        assert rig.name == name
        assert len(rig.cameras) == n_cams
        assert rig.lidar(rig.keyframe_lidar).channel == "LIDAR_TOP"
        for cam in rig.cameras:
            assert cam.K[0, 0] > 0 and cam.width > 0 and cam.height > 0
            assert np.allclose(cam.ego_T_cam[:3, :3] @ cam.ego_T_cam[:3, :3].T, np.eye(3), atol=1e-9)
    assert load_rig("av2").origin_height_m == pytest.approx(0.32)
    assert load_rig("nuscenes").origin_height_m == 0.0


def test_nuscenes_rig_matches_reference():
    rig = load_rig("nuscenes")
    assert set(rig.camera_channels) == set(NUSCENES_REF)
    for ch, (f, cx, cy, t, q) in NUSCENES_REF.items():
        cam = rig.camera(ch)
        assert (cam.width, cam.height) == (1600, 900)
        assert cam.K[0, 0] == pytest.approx(f, abs=1e-9) and cam.K[1, 1] == pytest.approx(f, abs=1e-9)
        assert cam.K[0, 2] == pytest.approx(cx, abs=1e-9) and cam.K[1, 2] == pytest.approx(cy, abs=1e-9)
        assert np.allclose(cam.ego_T_cam, T_from_quat_trans(q, t), atol=1e-12)
    lidar = rig.lidar("LIDAR_TOP")
    assert np.allclose(lidar.ego_T_lidar, T_from_quat_trans(NUSCENES_LIDAR_TOP[1], NUSCENES_LIDAR_TOP[0]),
                       atol=1e-12)


def test_virtual_lidar_top_is_the_nuscenes_one_above_ground():
    """AV2's virtual LIDAR_TOP sits at the same height above ground as nuScenes' (origin 0.32 m up)."""
    av2, nus = load_rig("av2"), load_rig("nuscenes")
    assert np.allclose(av2.with_origin_height(0.0).lidar("LIDAR_TOP").ego_T_lidar,
                       nus.lidar("LIDAR_TOP").ego_T_lidar, atol=1e-9)


@pytest.mark.parametrize("scale", [0.5, 0.25, 0.3, 1 / 3, 2.0])
def test_scaled_keeps_projection_consistent(scale):
    """A 3D point lands where the pixel-centre convention says: u' = (u + 0.5) * sx - 0.5."""
    rig = load_rig("nuscenes")
    small = rig.scaled(scale)
    assert small.scale == pytest.approx(scale)
    rng = np.random.default_rng(0)
    for cam, cam_s in zip(rig.cameras, small.cameras):
        sx, sy = cam_s.width / cam.width, cam_s.height / cam.height
        assert cam_s.width == round(cam.width * scale) and cam_s.height == round(cam.height * scale)
        assert np.array_equal(cam_s.ego_T_cam, cam.ego_T_cam)
        p_cam = np.column_stack([rng.uniform(-5, 5, 20), rng.uniform(-3, 3, 20), rng.uniform(2, 60, 20)])
        p_ego = transform_points(cam.ego_T_cam, p_cam)
        uv, uv_s = project(cam, p_ego), project(cam_s, p_ego)
        assert np.allclose(uv_s[:, 0], (uv[:, 0] + 0.5) * sx - 0.5, atol=1e-9)
        assert np.allclose(uv_s[:, 1], (uv[:, 1] + 0.5) * sy - 0.5, atol=1e-9)
    # The image corners (pixel edges) map onto the new image's edges.
    cam, cam_s = rig.cameras[0], small.cameras[0]
    edge = np.array([[-0.5, -0.5], [cam.width - 0.5, cam.height - 0.5]])
    sx, sy = cam_s.width / cam.width, cam_s.height / cam.height
    new_edge = np.column_stack([(edge[:, 0] + 0.5) * sx - 0.5, (edge[:, 1] + 0.5) * sy - 0.5])
    assert np.allclose(new_edge, [[-0.5, -0.5], [cam_s.width - 0.5, cam_s.height - 0.5]])


def test_scaled_round_trip_and_masks():
    rig = load_rig("av2")
    back = rig.scaled(0.5).scaled(2.0)
    for a, b in zip(rig.cameras, back.cameras):
        assert (a.width, a.height) == (b.width, b.height)
        assert np.allclose(a.K, b.K, atol=1e-9)
        for pa, pb in zip(a.ego_mask_polygons, b.ego_mask_polygons):
            assert np.allclose(pa, pb, atol=1e-9)
    front = rig.camera("ring_front_center")
    mask = front.ego_mask()
    assert mask.shape == (front.height, front.width)
    assert mask[1900, 700] and not mask[1000, 700]
    small_mask = rig.scaled(0.25).camera("ring_front_center").ego_mask()
    assert small_mask[480, 190] and not small_mask[400, 190]
    with pytest.raises(ValueError, match="scale must be > 0"):
        rig.scaled(0.0)


def test_with_origin_height_round_trip_keeps_the_physical_sensors():
    rig = load_rig("av2")
    ground = rig.with_origin_height(0.0)
    back = ground.with_origin_height(rig.origin_height_m)
    for a, g, b in zip(rig.cameras, ground.cameras, back.cameras):
        assert np.allclose(a.ego_T_cam, b.ego_T_cam, atol=1e-12)
        # Height above ground is unchanged: z_ego + origin height.
        assert g.ego_T_cam[2, 3] == pytest.approx(a.ego_T_cam[2, 3] + 0.32, abs=1e-12)
        assert np.allclose(g.ego_T_cam[:3, :3], a.ego_T_cam[:3, :3])
    # A point 1 m above ground, 20 m ahead projects to the same pixel in both frames.
    cam_a, cam_g = rig.camera("ring_front_center"), ground.camera("ring_front_center")
    assert np.allclose(project(cam_a, np.array([[20.0, 0.5, 1.0 - 0.32]])),
                       project(cam_g, np.array([[20.0, 0.5, 1.0]])), atol=1e-9)


def test_to_dict_round_trip():
    for name in ("nuscenes", "av2", "truck5"):
        rig = load_rig(name)
        again = rig_from_dict(json.loads(json.dumps(rig.to_dict())), "<round trip>")
        assert again.camera_channels == rig.camera_channels
        for a, b in zip(rig.cameras, again.cameras):
            assert np.allclose(a.K, b.K) and np.allclose(a.ego_T_cam, b.ego_T_cam, atol=1e-12)


def _mutated(tmp_path: Path, mutate) -> Path:
    spec = json.loads((RIG_SPEC_DIR / "nuscenes.json").read_text())
    spec = copy.deepcopy(spec)
    mutate(spec)
    path = tmp_path / "rig.json"
    path.write_text(json.dumps(spec))
    return path


def _set(spec, key, value, cam=0):
    spec["cameras"][cam][key] = value


@pytest.mark.parametrize(("mutate", "field"), [
    (lambda s: s["cameras"][0].pop("fx"), "cameras[0].fx"),
    (lambda s: s.pop("origin_height_m"), "origin_height_m"),
    (lambda s: s["lidars"][0].pop("rotation"), "lidars[0].rotation"),
    (lambda s: _set(s, "rotation", [1.0, 0.1, 0.0, 0.0]), "cameras[0].rotation"),
    (lambda s: _set(s, "fx", -1266.4), "cameras[0].fx"),
    (lambda s: _set(s, "fy", 0.0), "cameras[0].fy"),
    (lambda s: s.update(keyframe_lidar="LIDAR_FRONT"), "keyframe_lidar"),
    (lambda s: _set(s, "channel", "CAM FRONT"), "cameras[0].channel"),
    (lambda s: _set(s, "channel", "CAM_FRONT", cam=1), "cameras[1].channel"),
    (lambda s: _set(s, "width", 0), "cameras[0].width"),
    (lambda s: _set(s, "translation", [1.0, 2.0]), "cameras[0].translation"),
    (lambda s: _set(s, "cx", float("nan")), "cameras[0].cx"),
    (lambda s: _set(s, "ego_mask_polygons", [[[0, 0], [1, 1]]]), "cameras[0].ego_mask_polygons[0]"),
    # wrong JSON types, each was an internal TypeError or a message naming neither file nor field
    (lambda s: s.update(lidars=5), "lidars"),
    (lambda s: s.update(lidars=None), "lidars"),
    (lambda s: s.update(keyframe_lidar=["LIDAR_TOP"]), "keyframe_lidar"),
    (lambda s: s.update(extra=[1, 2]), "extra"),
    (lambda s: s.update(name=None), "name"),
    (lambda s: s.update(description=5), "description"),
    (lambda s: _set(s, "ego_mask_polygons", None), "cameras[0].ego_mask_polygons"),
    (lambda s: _set(s, "ego_mask_polygons", "abc"), "cameras[0].ego_mask_polygons"),
    (lambda s: _set(s, "ego_mask_polygons", [[[0, 0], [1], [2, 2]]]), "cameras[0].ego_mask_polygons[0]"),
    (lambda s: _set(s, "fx", 10 ** 400), "cameras[0].fx"),
    # a name too long for the file names it goes into (failed every log late, with errno 36)
    (lambda s: _set(s, "channel", "C" * 65), "cameras[0].channel"),
    # a misspelt optional field silently dropped the ego mask
    (lambda s: _set(s, "ego_mask_polygon", [[[0, 0], [9, 0], [9, 9]]]), "cameras[0]"),
    (lambda s: s["lidars"][0].update(rotaton=[1, 0, 0, 0]), "lidars[0]"),
    # nuScenes has one LiDAR channel, LIDAR_TOP; another name converted to a database no consumer reads
    (lambda s: (s["lidars"][0].update(channel="LIDAR_X"), s.update(keyframe_lidar="LIDAR_X")),
     "keyframe_lidar"),
    (lambda s: s["lidars"][0].update(channel="LIDAR_X"), "lidars"),
])
def test_validation_errors_name_file_and_field(tmp_path, mutate, field):
    path = _mutated(tmp_path, mutate)
    with pytest.raises(RigSpecError) as err:
        load_rig(path)
    assert str(path) in str(err.value)
    assert f"'{field}'" in str(err.value)


def test_unknown_rig_and_bad_json(tmp_path):
    with pytest.raises(RigSpecError, match="unknown rig 'no_such_rig'"):
        load_rig("no_such_rig")
    bad = tmp_path / "broken.json"
    bad.write_text("{not json")
    with pytest.raises(RigSpecError, match="not valid JSON") as err:
        load_rig(bad)
    assert str(bad) in str(err.value)
    with pytest.raises(RigSpecError, match="not found"):
        load_rig(tmp_path / "absent.json")
    with pytest.raises(RigSpecError, match="not found"):
        load_rig(tmp_path / "no_suffix")  # a path, not a name: not looked up among the built-in rigs
    spec = tmp_path / "myrig"  # an existing spec file without .json is read as that file
    spec.write_text((Path(__file__).resolve().parent.parent / "rig_specs" / "nuscenes.json").read_text())
    assert load_rig(spec).camera_channels == load_rig("nuscenes").camera_channels
