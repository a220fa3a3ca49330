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

import importlib

from nuav2.synth.config import FACTORS, LAYOUTS, PRESETS, SynthConfig

# The rest loads on first use (PEP 562): the CLI's parser needs only the names above, and the
# world, ray caster and renderer pull in numba and the map code (about 0.3 s).
_LAZY = {
    "generate_log": "nuav2.synth.log_writer",
    "LidarReturns": "nuav2.synth.raycast", "cast_sweep": "nuav2.synth.raycast",
    "REGION_LABELS": "nuav2.synth.render", "render_view": "nuav2.synth.render",
    "ActorPoses": "nuav2.synth.world", "SyntheticWorld": "nuav2.synth.world",
    "build_world": "nuav2.synth.world", "load_world": "nuav2.synth.world",
}


def __getattr__(name: str):
    if name not in _LAZY:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(_LAZY[name]), name)
    globals()[name] = value
    return value


__all__ = ["ActorPoses", "FACTORS", "LAYOUTS", "LidarReturns", "PRESETS", "SynthConfig", "SyntheticWorld",
           "build_world", "cast_sweep", "generate_log", "load_world", "render_view", "REGION_LABELS"]
