"""The devkit's ego-centric map underlay on what ``nuav2 convert`` writes (QA: blank on synthetic logs).

``NuScenesExplorer.render_ego_centric_map`` (used by ``render_sample_data(..., underlay_map=True)`` and so
by ``render_sample``) crops sqrt(2) x ``axes_limit`` around the ego from the map mask without clipping;
with too little canvas past the poses the crop came back empty (shape (0, 800)) and the lidar render
drew no map, silently. The ego drives on the road, so the underlay's centre must be drivable.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib
import numpy as np
import pytest
from e2e_helpers import SYNTH_SECONDS, VERSION, cli
from e2e_support import converted

matplotlib.use("Agg")
pytest_plugins = ["test_writer_support", "e2e_support"]


@pytest.fixture(scope="module")
def junction_db(tmp_path_factory) -> Path:
    """A ``medium`` world's y-junction (seed 3): its map reaches only ~35 m past the ego on one side."""
    root = tmp_path_factory.mktemp("underlay_synth")
    code, _, err = cli("synth", root, "--seed", 3, "--preset", "medium", "--seconds", SYNTH_SECONDS,
                       "--scale", 0.25)
    assert code == 0, err
    return converted(tmp_path_factory, "underlay_native", root / "train")


def underlays(db: Path, axes_limit_m: float) -> list[np.ndarray]:
    """The map image the devkit draws under each LIDAR_TOP sweep of the database."""
    import matplotlib.pyplot as plt
    from nuscenes import NuScenes

    nusc = NuScenes(VERSION, str(db), verbose=False)
    images = []
    for sd in nusc.sample_data:
        if sd["channel"] != "LIDAR_TOP":
            continue
        _, ax = plt.subplots()
        nusc.explorer.render_ego_centric_map(sd["token"], axes_limit=axes_limit_m, ax=ax)
        images.append(np.asarray(ax.get_images()[0].get_array()))
        plt.close("all")
    return images


@pytest.mark.parametrize("db_fixture", ["junction_db", "native_synth_db", "warp_db", "native_fixture_db"])
# the devkit's default axes limit, and one near the 56 m the margin serves
@pytest.mark.parametrize("axes_limit_m", [40.0, 55.0])
def test_the_lidar_underlay_is_the_whole_map_around_the_ego(db_fixture: str, axes_limit_m: float, request):
    images = underlays(request.getfixturevalue(db_fixture), axes_limit_m)
    assert images
    side = 2 * int(axes_limit_m / 0.1)
    for img in images:
        assert img.shape[:2] == (side, side)  # an uncropped window (a canvas edge gave (0, side) or less)
        centre = img[side // 2 - 5: side // 2 + 5, side // 2 - 5: side // 2 + 5]
        assert (centre > 0).all()  # the ego stands on the drivable area
