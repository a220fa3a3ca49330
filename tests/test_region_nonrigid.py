"""Non-rigid actors (pedestrians, cyclists) are their own scored region: truth_view labels their pixels, the
region is part of "objects", and RegionScores reports it (None where no such actor is in view)."""

from __future__ import annotations

import numpy as np
import pytest

from nuav2.actor_tracks import is_non_rigid
from nuav2.evaluate.against_world import LABEL_NONRIGID, RegionScores, truth_view, world_region_masks
from nuav2.rig import load_rig
from nuav2.synth import REGION_LABELS, SynthConfig, build_world, render_view


def test_truth_view_labels_the_pixels_of_non_rigid_actors():
    world = build_world(seed=3, config=SynthConfig(seconds=0.5, n_parked=2, n_moving=1, n_pedestrians=3,
                                                   map_margin_m=30.0))
    soft = {i for i, a in enumerate(world.actors) if is_non_rigid(a.category)}
    assert soft and len(soft) < len(world.actors)
    rig = load_rig("av2", scale=0.125)
    t = int(world.timeline.sweeps_ns[2])
    seen = 0
    for cam in rig.cameras[:7]:
        city_T_cam = world.city_T_ego_at(t) @ cam.ego_T_cam
        img, labels = truth_view(world, cam, city_T_cam, t)
        raw_img, raw_labels, owner = render_view(world, cam, city_T_cam, t, with_labels=True,
                                                 with_owners=True)
        np.testing.assert_array_equal(img, raw_img)
        expect = np.isin(owner, list(soft))
        np.testing.assert_array_equal(labels == LABEL_NONRIGID, expect)
        masks = world_region_masks(labels)
        assert not (masks["nonrigid"] & ~masks["objects"]).any()  # a subset of the objects
        np.testing.assert_array_equal(masks["objects"], raw_labels == REGION_LABELS["objects"])
        seen += int(expect.sum())
        scores = RegionScores()
        got = scores.add(cam, city_T_cam, img, img, labels)
        assert (got["nonrigid"] is None) == (not expect.any())
    assert seen > 0  # some pedestrian is in view of some camera


def test_summary_has_the_region_with_none_where_nothing_was_in_view():
    scores = RegionScores()
    cam = load_rig("nuscenes", scale=0.05).cameras[0]
    truth = np.full((cam.height, cam.width, 3), 100, np.uint8)
    labels = np.full((cam.height, cam.width), REGION_LABELS["ground"], np.uint8)
    scores.add(cam, np.eye(4), truth, truth, labels)
    assert scores.summary()["psnr_db"]["nonrigid"] is None
    labels[10:30, 20:50] = LABEL_NONRIGID  # >= 64 pixels away from the border: scored
    noisy = truth.copy()
    noisy[10:30, 20:50] = 90
    scores.add(cam, np.eye(4), noisy, truth, labels)
    assert scores.summary()["psnr_db"]["nonrigid"] == pytest.approx(20 * np.log10(255 / 10), abs=0.01)
