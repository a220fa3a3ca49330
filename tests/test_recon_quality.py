"""Quality gate: which target points count as seen by the source cameras (hand-built oracles)."""

from __future__ import annotations

import numpy as np

from nuav2.geometry import T_inverse, make_T
from nuav2.rig import CameraSpec
from nuav2.splat.quality import QualityConfig, SourceCoverage, image_quality

CAM_R_FORWARD_X = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
K = np.array([[50.0, 0.0, 49.5], [0.0, 50.0, 29.5], [0.0, 0.0, 1.0]])


def one_source(depth: np.ndarray | None = None) -> SourceCoverage:
    """A single source camera at the origin looking along +x, 100 x 60 px (~90 deg wide)."""
    scene_T_cam = make_T(CAM_R_FORWARD_X, [0.0, 0.0, 0.0])
    return SourceCoverage(T_inverse(scene_T_cam)[None], K[None], np.array([[100, 60]]), [depth], 0.25)


def test_point_coverage_rules():
    cov = one_source()
    cfg = QualityConfig(max_angle_deg=25.0, max_distance_ratio=3.0)
    pts = np.array([
        [10.0, 0.0, 0.0],   # straight ahead, target right behind the source: covered
        [-10.0, 0.0, 0.0],  # behind the source camera
        [10.0, 30.0, 0.0],  # outside the field of view
        [10.0, 0.0, 0.0],   # seen, but the target looks at it from the side (90 deg)
    ])
    targets = [np.array([-1.0, 0.0, 0.0]), np.array([-1.0, 0.0, 0.0]), np.array([-1.0, 0.0, 0.0]),
               np.array([10.0, -10.0, 0.0])]
    got = [bool(cov.covered(p[None], t, np.array([False]), cfg)[0]) for p, t in zip(pts, targets)]
    assert got == [True, False, False, False]
    # A target 10x closer to the point than the source sees it much sharper: not covered.
    solid = np.array([False])
    assert not cov.covered(np.array([[40.0, 0.0, 0.0]]), np.array([38.0, 0.0, 0.0]), solid, cfg)[0]
    # Directions (sky) only need to be in some source's field of view.
    dirs = np.array([[1.0, 0.1, 0.2], [-1.0, 0.0, 0.2]])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    got = cov.covered(dirs, np.array([500.0, 500.0, 0.0]), np.array([True, True]), cfg)
    assert got.tolist() == [True, False]


def test_occlusion_by_source_depth():
    depth = np.full((15, 25), np.inf, np.float32)
    depth[5:10, 10:15] = 5.0  # a wall 5 m ahead in the middle of the source view
    cov = one_source(depth)
    cfg = QualityConfig()
    behind_wall = np.array([[20.0, 0.0, 0.0]])
    assert not cov.covered(behind_wall, np.array([-1.0, 0.0, 0.0]), np.array([False]), cfg)[0]
    on_wall = np.array([[5.0, 0.0, 0.0]])
    assert cov.covered(on_wall, np.array([-1.0, 0.0, 0.0]), np.array([False]), cfg)[0]


def test_image_quality_from_rendered_depth():
    cov = one_source()
    cam = CameraSpec("T", 100, 60, K, np.eye(4))
    scene_T_cam = make_T(CAM_R_FORWARD_X, [0.5, 0.0, 0.0])  # just ahead of the source: all covered
    depth = np.full((60, 100), 10.0, np.float32)
    alpha = np.ones((60, 100), np.float32)
    q = image_quality(depth, alpha, cam, scene_T_cam, cov)
    assert q.confidence == 1.0 and q.solid_fraction == 1.0 and q.samples == 48 * 27
    # Stepping back 0.5 m widens the view at 10 m past the source's: the edge columns lose coverage.
    wider = image_quality(depth, alpha, cam, make_T(CAM_R_FORWARD_X, [-0.5, 0.0, 0.0]), cov)
    assert 0.8 < wider.confidence < 1.0
    # Looking backwards (+180 deg yaw): nothing the source saw.
    back = make_T(np.diag([-1.0, -1.0, 1.0]) @ CAM_R_FORWARD_X, [0.5, 0.0, 0.0])
    assert image_quality(depth, alpha, cam, back, cov).confidence == 0.0
    # Sky pixels (alpha 0) in the source's field of view count as covered.
    sky = image_quality(depth, np.zeros_like(alpha), cam, scene_T_cam, cov)
    assert sky.solid_fraction == 0.0 and sky.confidence == 1.0


def test_a_non_rigid_actor_in_view_lowers_confidence():
    """A pedestrian box 10 m ahead covering the image centre: its samples never count as covered."""
    cov = one_source()
    cam = CameraSpec("T", 100, 60, K, np.eye(4))
    scene_T_cam = make_T(CAM_R_FORWARD_X, [0.5, 0.0, 0.0])
    depth = np.full((60, 100), 10.0, np.float32)
    alpha = np.ones((60, 100), np.float32)
    # The box spans y and z in [-1, 1] (x 1.15 grown) at x = 10.5 (camera depth 10): 11.5 x 11.5 px at f = 50.
    box = make_T(np.eye(3), [10.5, 0.0, 0.0])[None]
    q = image_quality(depth, alpha, cam, scene_T_cam, cov, nonrigid_boxes=(box, np.array([[1.0, 2.0, 2.0]])))
    expect = 11.5 * 11.5 / (100 * 60)  # share of the image inside the projected box
    assert 0.7 * expect < q.nonrigid_fraction < 1.3 * expect
    assert q.confidence == 1.0 - q.nonrigid_fraction
    far = make_T(np.eye(3), [40.0, 0.0, 0.0])[None]  # behind the rendered surface: not in view
    assert image_quality(depth, alpha, cam, scene_T_cam, cov,
                         nonrigid_boxes=(far, np.array([[1.0, 2.0, 2.0]]))).nonrigid_fraction == 0.0
