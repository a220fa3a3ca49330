"""The road behind an ego that waits at a junction: a target camera looking back must see road there.

No source camera sees the road just behind the ego's body while it stands still; its ground seeds were
dropped and SSIM at the body mask's edge made what remained see-through, so nuScenes' CAM_BACK showed
the sky's colour on the road (docs/reconstruction.md, "The road behind a waiting ego").
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from converters.av2 import read_log
from nuav2.evaluate.against_world import truth_view
from nuav2.recon import ReconConfig, reconstruct
from nuav2.rig import load_rig
from nuav2.splat.densify import DensifyConfig
from nuav2.splat.init import InitConfig
from nuav2.splat.render_target import target_city_T_cams, to_uint8
from nuav2.splat.train import TrainConfig
from nuav2.synth import REGION_LABELS, SynthConfig, generate_log, load_world

# seed 0 with layouts: a T-junction where the ego stands still for the whole 0.5 s
WAITING = SynthConfig.for_preset("easy", layouts=True, seconds=0.5, image_scale=1 / 16,
                                 lidar_azimuth_steps=256, n_parked=2, n_moving=1, n_pedestrians=0,
                                 map_margin_m=30.0)


def _config(**init) -> ReconConfig:
    train = TrainConfig(iterations=200, pyramid=(0.5, 1.0), pyramid_until=(0.3,),
                        densify=DensifyConfig(start=50, every=50, stop=160, budget=30_000, reset_every=0))
    base = InitConfig(max_background=20_000, ground_spacing_m=0.4, ground_radius_m=15.0)
    return ReconConfig(sh_degree=0, train_width_px=128, holdout_every=5, init=replace(base, **init),
                       train=train)


@pytest.fixture(scope="module")
def waiting(tmp_path_factory):
    log = generate_log(tmp_path_factory.mktemp("waiting_ego"), seed=0, config=WAITING)
    scene, world = read_log(log), load_world(log)
    path = scene.city_T_ego[:, :3, 3]
    assert np.linalg.norm(path[-1] - path[0]) < 0.05  # the ego really waits
    return scene, world


def _back_ground_error(splat, scene, world) -> float:
    """Mean absolute error (8-bit) of CAM_BACK's road pixels in the lower third, at the middle sweep."""
    cam = load_rig("nuscenes", scale=1 / 16).camera("CAM_BACK")
    t = int(scene.sweep_timestamps_ns[len(scene.sweep_timestamps_ns) // 2])
    city_T_cam = target_city_T_cams(scene, load_rig("nuscenes", scale=1 / 16), t)["CAM_BACK"]
    img = to_uint8(splat.render(cam, city_T_cam, t).rgb).astype(float)
    truth, labels = truth_view(world, cam, city_T_cam, t)
    road = labels == REGION_LABELS["ground"]
    road[: 2 * cam.height // 3] = False
    assert road.sum() > 100
    return float(np.abs(img - truth.astype(float))[road].mean())


def test_the_road_behind_a_waiting_ego_is_road(waiting):
    """Two things keep the sky off that road: the unseen ground is filled with seeds, and the sky's rows
    below the horizon hold the road's colour where the road is still partly transparent. Either alone
    keeps the error far below the 28.9 measured when the sky's colour showed there."""
    scene, world = waiting
    splat = reconstruct(scene, _config(), progress=False)
    assert splat.info["init_stats"]["unseen_ground_seeds"] > 0
    error = _back_ground_error(splat, scene, world)
    dropped = reconstruct(scene, _config(unseen_ground_reach_m=0.0), progress=False)
    assert dropped.info["init_stats"]["unseen_ground_seeds"] == 0
    below = _back_ground_error(dropped, scene, world)  # only the road-coloured sky below the horizon
    assert error < 12.0 and below < 12.0  # measured at writing: 8.0 and 8.3
