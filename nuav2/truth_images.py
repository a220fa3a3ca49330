"""Truth mode's image provider: a synthetic log's saved world rendered exactly in the target rig.

``nuav2 convert av2 SRC OUT --mode truth --rig nuscenes`` writes what a nuScenes car would have
recorded driving the synthetic world along the log's trajectory: the ground-truth renderer
(:func:`nuav2.synth.render_view`) draws each target camera at the pose the writer hands it
(``city_T_camT = city_T_egoS(t) @ egoS_T_egoT @ egoT_T_camT``), actors at that time. It is the
stand-in for "real target-rig data" in the transfer benchmark (the oracle): same worlds, the
target rig, exact images. Only logs written by ``nuav2 synth`` have a world to render; a real AV2
log is refused with a one-line error.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from nuav2.geometry import F64
from nuav2.nuscenes_db.images import ImageSourceError, RenderedImages
from nuav2.rig import CameraSpec
from nuav2.scene import SceneLog

# How far above a sensor file the log directory sits (sensors/lidar/<ts>.feather,
# sensors/cameras/<channel>/<ts>.jpg).
_LOG_DIR_DEPTH = (2, 3)


def synthetic_log_dir(scene: SceneLog) -> Path:
    """The directory of ``scene``'s log holding ``synthetic_world.json``; ImageSourceError when none does."""
    from nuav2.synth.world import WORLD_FILE

    files = [s.path for s in scene.lidar_sweeps[:1]]
    files += [f.path for frames in scene.camera_frames.values() for f in frames[:1]]
    candidates = []
    for path in files:
        for depth in _LOG_DIR_DEPTH:
            if len(Path(path).parents) > depth:
                candidates.append(Path(path).parents[depth])
    for log_dir in candidates:
        if (log_dir / WORLD_FILE).is_file():
            return log_dir
    where = candidates[0] if candidates else f"log {scene.log_id}"
    raise ImageSourceError(
        f"{where}: --mode truth needs a synthetic log written by `nuav2 synth` "
        f"(no {WORLD_FILE}); a real AV2 log has no ground-truth world to render"
    )


class WorldRenderer:
    """A :data:`nuav2.nuscenes_db.images.RenderFn` drawing the synthetic world of one log."""

    def __init__(self, log_dir: Path) -> None:
        from nuav2.synth import load_world

        try:
            self.world = load_world(log_dir)
        except (FileNotFoundError, ValueError) as e:
            raise ImageSourceError(str(e)) from e

    def __call__(self, channel: str, camera: CameraSpec, city_T_cam: F64, timestamp_ns: int) -> np.ndarray:
        from nuav2.synth import render_view

        return render_view(self.world, camera, city_T_cam, int(timestamp_ns))


def truth_image_source(scene: SceneLog) -> RenderedImages:
    """Truth mode's writer ``ImageSource`` for one synthetic log (one image per camera per sample)."""
    return RenderedImages(WorldRenderer(synthetic_log_dir(scene)), name="truth")
