"""Synthetic AV2 sensor logs from a procedural world, and a ground-truth renderer for any rig.

Public API (stable; reconstruction and warp code call it)::

    from nuav2.synth import SynthConfig, generate_log, load_world, render_view

    cfg = SynthConfig.for_preset("hard")                # or "easy" (the default), "medium"
    log_dir = generate_log(out_dir, seed=0, config=cfg) # out_dir/train/<log_id>/ in AV2 layout
    world = load_world(log_dir)                         # the world behind that log
    img, depth = render_view(world, cam, city_T_cam, timestamp_ns, with_depth=True)
    img, labels = render_view(world, cam, city_T_cam, timestamp_ns, with_labels=True)  # REGION_LABELS
    world.city_T_ego_at(ts); world.actor_poses_at(ts)   # ground-truth poses

Realism presets (``PRESETS``) and their factors (``FACTORS``) are described in config.py and
docs/realism.md; ``LAYOUTS`` are the road layouts ``SynthConfig.layout`` can pick.
"""

from nuav2.synth.config import FACTORS, LAYOUTS, PRESETS, SynthConfig
from nuav2.synth.log_writer import generate_log
from nuav2.synth.raycast import LidarReturns, cast_sweep
from nuav2.synth.render import REGION_LABELS, render_view
from nuav2.synth.world import ActorPoses, SyntheticWorld, build_world, load_world

__all__ = ["ActorPoses", "FACTORS", "LAYOUTS", "LidarReturns", "PRESETS", "SynthConfig", "SyntheticWorld",
           "build_world", "cast_sweep", "generate_log", "load_world", "render_view", "REGION_LABELS"]
