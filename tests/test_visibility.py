"""nuScenes visibility measured in the output cameras (nuav2/nuscenes_db/visibility.py).

Geometry cases with known answers, then the tokens ``nuav2 convert`` writes against an oracle
(``nuav2.bench.visibility_check``): the synthetic world's exact depth render (an independent
renderer) decides, pixel by pixel, whether the annotated box's own actor or something in front of
it is seen.
"""

from __future__ import annotations

import collections
import json
from pathlib import Path

import numpy as np
import pytest
from e2e_helpers import convert

from nuav2.bench.visibility_check import agreement, main, measure_cost, oracle_fractions
from nuav2.geometry import make_T
from nuav2.nuscenes_db.visibility import VisibilityCamera, box_visibility, occluder_points, visibility_token

pytest_plugins = ["test_writer_support", "e2e_support"]

# A camera at the ego origin, 1.5 m up, looking along ego +x (camera z forward, x right, y down).
ego_R_cam = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
K = np.array([[400.0, 0.0, 400.0], [0.0, 400.0, 300.0], [0.0, 0.0, 1.0]])
FRONT = VisibilityCamera(K, make_T(ego_R_cam, [0.0, 0.0, 1.5]), 800, 600)
BACK = VisibilityCamera(K, make_T(np.diag([-1.0, -1.0, 1.0]) @ ego_R_cam, [0.0, 0.0, 1.5]), 800, 600)


def box(x: float, y: float, z: float = 1.0, lwh=(2.0, 2.0, 2.0)) -> tuple[np.ndarray, np.ndarray]:
    return make_T(np.eye(3), [x, y, z]), np.asarray(lwh, float)


def vis(boxes, cameras=(FRONT,), points=None) -> np.ndarray:
    points = np.zeros((0, 3)) if points is None else points
    T = np.stack([b[0] for b in boxes])
    size = np.stack([b[1] for b in boxes])
    return box_visibility(T, size, list(cameras), occluder_points(points, T, size))


def test_tokens_follow_the_nuscenes_bins():
    assert [visibility_token(f) for f in (0.0, 0.39, 0.4, 0.59, 0.6, 0.79, 0.8, 1.0)] == \
        ["1", "1", "2", "2", "3", "3", "4", "4"]


def test_a_box_alone_in_view_is_fully_visible_and_one_behind_the_camera_is_not():
    np.testing.assert_allclose(vis([box(10, 0)]), [1.0])
    assert vis([box(-10, 0)])[0] == 0.0
    assert vis([box(-10, 0)], cameras=(FRONT, BACK))[0] == pytest.approx(1.0)


def test_boxes_hide_boxes_behind_them_in_proportion():
    hidden = vis([box(20, 0), box(8, 0, lwh=(2, 4, 4))])
    assert hidden[0] == 0.0 and hidden[1] == 1.0
    # The near box's core (OCCLUDER_CORE of it: y 0 to 3.6 m) covers the left half (ego +y) of the far
    # one's image.
    half = vis([box(20, 0), box(10, 1.8, lwh=(1.0, 4.0, 4.0))])
    assert 0.35 < half[0] < 0.65 and visibility_token(half[0]) in ("1", "2")
    assert half[1] == 1.0


def test_lidar_walls_hide_boxes_but_ground_and_the_boxes_own_points_do_not():
    g = np.mgrid[-5:30:0.2, -10:10:0.2].reshape(2, -1).T
    ground = np.c_[g, np.zeros(len(g))]
    target = box(20, 0)
    own = np.c_[np.full(200, 19.0), np.linspace(-0.9, 0.9, 200), np.linspace(0.1, 1.9, 200)]
    assert vis([target], points=np.r_[ground, own])[0] == pytest.approx(1.0)
    w = np.mgrid[-4:4:0.1, 0:3:0.1].reshape(2, -1).T
    wall = np.c_[np.full(len(w), 10.0), w]
    assert vis([target], points=np.r_[ground, wall])[0] < 0.05
    # A wall just behind the box's front face (within the margin) is its own clutter, not in front.
    close = np.c_[np.full(len(w), 18.9), w]
    assert vis([target], points=np.r_[ground, close])[0] > 0.9


def test_the_ego_body_mask_hides_what_is_behind_it():
    mask = np.zeros((600, 800), bool)
    mask[:, :400] = True  # the image's left half: ego +y
    cam = VisibilityCamera(FRONT.K, FRONT.ego_T_cam, 800, 600, mask)
    assert vis([box(20, 3)], cameras=(cam,))[0] == 0.0
    assert vis([box(20, -3)], cameras=(cam,))[0] == 1.0


def test_hard_cases_stay_finite():
    inside = box(0.0, 0.0, 1.5, lwh=(3, 3, 3))  # the camera inside a box
    straddle = box(0.5, 0.0, 1.5, lwh=(2, 2, 2))  # across the camera plane
    tiny = box(5000.0, 0.0, lwh=(1e-3, 1e-3, 1e-3))
    flat = box(10, 0, lwh=(2, 2, 1e-9))
    out = vis([inside, straddle, tiny, flat], points=np.array([[np.nan, 0, 0], [np.inf, 1, 1], [10, 0, 1.0]]))
    assert np.all(np.isfinite(out)) and np.all((out >= 0) & (out <= 1))
    assert vis([inside])[0] == 1.0  # nothing but itself in front of the camera
    assert len(box_visibility(np.zeros((0, 4, 4)), np.zeros((0, 3)), [FRONT], np.zeros((0, 3)))) == 0


def test_written_tokens_match_the_exact_render_on_an_easy_world(warp_db: Path, synth_log: Path):
    fractions = oracle_fractions(warp_db, synth_log)
    assert len(fractions) >= 20
    score = agreement(fractions)
    assert score["same_bin_share"] >= 0.9 and score["within_one_share"] == 1.0, score
    written = collections.Counter(t for _, t in fractions.values())
    assert written["4"] < len(fractions) and written["4"] > 0  # measured, not a constant


def test_the_check_command_writes_its_json_with_the_cost(warp_db: Path, synth_log: Path, tmp_path: Path):
    assert main([str(warp_db), str(synth_log), "--rig", "nuscenes", "--scale", "0.25",
                 "--json", str(tmp_path / "v.json")]) == 0
    result = json.loads((tmp_path / "v.json").read_text())
    assert result["same_bin"] <= result["within_one_bin"] <= result["annotations"]
    assert result["cost"]["cameras"] == 6 and result["cost"]["cpu_s_per_sample"] > 0


@pytest.fixture(scope="module")
def hard_pair(tmp_path_factory) -> tuple[Path, Path]:
    """A 1 s ``hard`` world (label noise, noisy LiDAR, shaped bodies, relief) converted by warp."""
    from e2e_helpers import cli

    root = tmp_path_factory.mktemp("vis_hard")
    code, stdout, stderr = cli("synth", root / "src", "--seed", 1, "--preset", "hard", "--seconds", "1")
    assert code == 0, stderr
    log_dir = Path(json.loads(stdout)["log_dir"])
    out = root / "out"
    convert(log_dir.parent, out, "--mode", "warp", "--rig", "nuscenes", "--scale", "0.25")
    return out, log_dir


def test_written_tokens_match_the_exact_render_on_a_hard_world(hard_pair):
    """Label noise, LiDAR noise and bodies that do not fill their boxes make the measure coarser."""
    score = agreement(oracle_fractions(*hard_pair))
    assert score["annotations"] >= 40
    assert score["same_bin_share"] >= 0.8 and score["within_one_share"] >= 0.9, score


def test_real_fixture_log_gets_measured_tokens(native_fixture_db: Path, fixture_log: Path):
    """The real AV2 fragment (one annotated sweep, 44 boxes within 176 m) in its own cameras, with the
    ego-body masks: the tokens are real ones and not one constant. ``-s`` prints them and the cost."""
    v = native_fixture_db / "v1.0-nuav2"
    anns = json.loads((v / "sample_annotation.json").read_text())
    written = collections.Counter(a["visibility_token"] for a in anns)
    print("fixture visibility tokens", dict(sorted(written.items())))
    assert len(written) >= 2 and set(written) <= {"1", "2", "3", "4"}
    cost = measure_cost(fixture_log, None, 1.0, skip_first=False)
    print("fixture visibility cost", json.dumps(cost))
    assert cost["samples_timed"] == 1 and cost["points_per_sample"] > 50_000


def test_a_database_without_cameras_keeps_the_unknown_token(synth_log: Path, tmp_path: Path):
    """Nothing to measure in: every box gets "4", as before visibility was measured."""
    import shutil

    log_dir = tmp_path / "src" / synth_log.parent.name / synth_log.name
    shutil.copytree(synth_log, log_dir,
                    ignore=lambda d, names: ["cameras"] if Path(d).name == "sensors" else [])
    convert(log_dir.parent, tmp_path / "db", "--allow-missing-cameras")
    anns = json.loads((tmp_path / "db" / "v1.0-nuav2" / "sample_annotation.json").read_text())
    assert anns and {a["visibility_token"] for a in anns} == {"4"}


def test_a_rider_and_its_bicycle_do_not_hide_each_other():
    """AV2 labels a cyclist and the bicycle as two intersecting boxes (both vehicle.bicycle here)."""
    bike = box(10, 0, 0.5, lwh=(1.8, 0.6, 1.0))
    rider = box(10, 0, 1.2, lwh=(0.8, 0.6, 1.7))
    np.testing.assert_allclose(vis([bike, rider]), [1.0, 1.0])
    # Apart, the nearer one hides the farther one.
    assert vis([box(20, 0, 1.0, lwh=(1.8, 0.6, 1.9)), box(10, 0, 1.2, lwh=(0.8, 1.0, 3.0))])[0] < 0.4


def test_a_box_around_the_camera_hides_nothing():
    """A label error can put the camera inside a box; that box then must not blank the whole image."""
    around = box(0.0, 0.0, 1.5, lwh=(3, 3, 3))
    np.testing.assert_allclose(vis([around, box(20, 0), box(15, 5)])[1:], [1.0, 1.0])
