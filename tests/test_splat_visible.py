"""Per-view culling before gathering (nuav2.splat.visible): it must change no pixel, only the work."""

from __future__ import annotations

import math

import numpy as np
import torch
from warp_scenes import EGO_R_CAM_FORWARD as CAM_R_FORWARD_X
from warp_scenes import camera

from nuav2.geometry import make_T, translation_T
from nuav2.splat import rasterize
from nuav2.splat.scene_model import (
    SH_C0,
    GaussianSet,
    ObjectModel,
    SkyModel,
    SplatScene,
    TrackPoses,
    raster_K,
)
from nuav2.splat.visible import frustum_cull


def random_set(rng: np.random.Generator, n: int, centre, spread: float) -> GaussianSet:
    means = np.asarray(centre) + rng.normal(scale=spread, size=(n, 3))
    return GaussianSet.create(means, rng.uniform(size=(n, 3)), rng.uniform(0.05, 0.6, size=(n, 3)),
                              opacity=0.6, sh_degree=0, quats=rng.normal(size=(n, 4)))


def test_numba_cull_matches_torch_cull():
    """The CPU float32 pass keeps the same rows as the torch test (float64 input) except at the
    frustum's boundary, where float32 rounding may decide."""
    rng = np.random.default_rng(0)
    g = random_set(rng, 20_000, [0, 0, 0], 30.0)
    cam = camera(64, 40, 40.0)
    scene_T_cam = make_T(CAM_R_FORWARD_X, [1.0, 2.0, 1.5])
    fast = set(frustum_cull(g.tensors(), cam, scene_T_cam, 0.1, 1000.0).tolist())
    as_f64 = {k: v.double() for k, v in g.tensors().items()}
    ref = set(frustum_cull(as_f64, cam, scene_T_cam, 0.1, 1000.0).tolist())
    assert 0 < len(ref) < len(g)
    assert len(fast ^ ref) <= 2, sorted(fast ^ ref)


def test_frustum_cull_drops_only_what_cannot_touch_the_view():
    """Rows behind the camera or far outside the field of view go; rows in view stay."""
    cam = camera(64, 40, 40.0)
    scene_T_cam = make_T(CAM_R_FORWARD_X, [0.0, 0.0, 0.0])
    means = np.array([[10.0, 0, 0], [-10.0, 0, 0], [10.0, 50.0, 0], [10.0, 0, -40.0], [0.05, 0, 0]])
    g = GaussianSet.create(means, np.full((5, 3), 0.5), np.full(5, 0.01))
    kept = frustum_cull(g.tensors(), cam, scene_T_cam, 0.1, 1000.0).tolist()
    assert kept == [0]
    big = GaussianSet.create(means, np.full((5, 3), 0.5), np.full(5, 30.0))  # 3 sigma reaches the view
    assert frustum_cull(big.tensors(), cam, scene_T_cam, 0.1, 1000.0).tolist() == [0, 1, 2, 3, 4]


def two_object_scene() -> SplatScene:
    rng = np.random.default_rng(3)
    bg = random_set(rng, 3000, [15.0, 0.0, 0.0], 12.0)
    ts = np.array([0, 10**9], np.int64)
    ahead = TrackPoses("ahead", "REGULAR_VEHICLE", np.array([4.0, 2.0, 1.5]), ts,
                       np.stack([translation_T(8.0, 1.0, 0.0), translation_T(9.0, 1.0, 0.0)]))
    behind = TrackPoses("behind", "REGULAR_VEHICLE", np.array([4.0, 2.0, 1.5]), ts,
                        np.stack([translation_T(-12.0, 0.0, 0.0), translation_T(-11.0, 0.0, 0.0)]))
    objects = [ObjectModel(tr, random_set(rng, 200, [0, 0, 0], 0.8)) for tr in (ahead, behind)]
    for o in objects:
        o.track.pose_delta = torch.zeros(2, 4, requires_grad=True)
    scene = SplatScene(np.eye(4), bg, objects, SkyModel(8, 16))
    for s in [scene.background, *(o.gaussians for o in objects)]:
        s.requires_grad_(True)
    return scene


def test_culled_render_equals_rendering_everything():
    """The image from the culled gather is the image of all Gaussians; an object behind the camera
    is left out of the render (no slice, no gradient) and the one ahead gets gradients."""
    scene = two_object_scene()
    cam = camera(64, 40, 40.0)
    city_T_cam = make_T(CAM_R_FORWARD_X, [0.0, 0.0, 1.0])
    t = 5 * 10**8
    out = scene.render(cam, city_T_cam, t, with_sky=False)
    assert set(out.slices) == {"background", "ahead", "behind"}  # both present at t
    everything, _ = scene.gather(t)
    full = rasterize(everything["means"], everything["quats"], everything["log_scales"],
                     everything["opacity_logits"], (SH_C0 * everything["sh"][:, 0] + 0.5).clamp_min(0.0),
                     scene.scene_T_city @ city_T_cam, raster_K(cam.K), cam.width, cam.height,
                     near=scene.near, far=scene.far)
    assert float(out.alpha.detach().max()) > 0.5
    np.testing.assert_allclose(out.rgb.detach().numpy(), full.rgb.detach().numpy(), atol=1e-6)
    np.testing.assert_allclose(out.depth.detach().numpy(), full.depth.detach().numpy(), atol=1e-4)
    out.rgb.sum().backward()
    ahead, behind = scene.objects
    assert ahead.gaussians.means.grad is not None and float(ahead.gaussians.means.grad.abs().sum()) > 0
    assert ahead.track.pose_delta.grad is not None
    assert behind.gaussians.means.grad is None and behind.track.pose_delta.grad is None
    # index holds the kept rows of the slices' numbering, in order: all of the object ahead, none behind
    assert torch.all(out.index[1:] > out.index[:-1])
    kept = set(out.index.tolist())
    ahead_rows, behind_rows = (set(range(out.slices[k].start, out.slices[k].stop))
                               for k in ("ahead", "behind"))
    assert ahead_rows <= kept and not (behind_rows & kept)


def test_objects_are_judged_by_their_whole_extent():
    """An object whose box origin is out of view but whose Gaussians reach into it is rendered:
    the bounding sphere follows the Gaussians, not the box."""
    scene = two_object_scene()
    behind = scene.objects[1]
    with torch.no_grad():
        behind.gaussians.means[0] = torch.tensor([25.0, 0.0, 1.0])  # 25 m ahead of the box origin
    cam = camera(64, 40, 40.0)
    city_T_cam = make_T(CAM_R_FORWARD_X, [0.0, 0.0, 1.0])
    out = scene.render(cam, city_T_cam, 5 * 10**8, with_sky=False)
    sl = out.slices["behind"]
    assert set(range(sl.start, sl.stop)) <= set(out.index.tolist())


def test_bounding_radius_follows_in_place_updates():
    g = GaussianSet.create(np.array([[1.0, 0, 0], [0, 2.0, 0]]), np.full((2, 3), 0.5), np.full(2, 0.1))
    r0 = g.bounding_radius()
    assert math.isclose(r0, 2.0 + 0.3, rel_tol=1e-6)
    with torch.no_grad():
        g.means.mul_(2.0)  # as an optimizer step does: in place
    assert math.isclose(g.bounding_radius(), 4.0 + 0.3, rel_tol=1e-6)
    assert GaussianSet.empty().bounding_radius() == 0.0



def test_bounding_radius_follows_the_training_optimizer_step():
    """Fused Adam updates in place without bumping the version counter the cache is keyed on: the
    step must bump it, or an object that moved or grew is culled from views that see it."""
    from nuav2.splat.optimizer import build_optimizer, step_groups_with_grads
    from nuav2.splat.train import TrainConfig

    scene = two_object_scene()
    g = scene.objects[0].gaussians
    before = g.bounding_radius()
    optimizer = build_optimizer(scene, TrainConfig(), extent=20.0)
    (group,) = [grp for grp in optimizer.param_groups if grp["params"][0] is g.means]
    group["lr"] = 1.0
    for _ in range(5):
        g.means.grad = torch.tensor([[-1.0, 0.0, 0.0]]).expand_as(g.means).clone()
        step_groups_with_grads(optimizer)
    with torch.no_grad():
        fresh = float((g.means.norm(dim=-1) + 3.0 * g.log_scales.exp().amax(-1)).amax())
    assert fresh > before + 3.0  # the means moved ~1 m per step
    assert math.isclose(g.bounding_radius(), fresh, rel_tol=1e-6)
