"""Databases for the info-export tests, built once per session (no tests here).

- ``curved_log`` / ``curved_db``: a 0.6 s synthetic AV2 log on the ``curved`` layout (the ego turns
  while cruising), with the two stereo cameras as real AV2 logs have, converted by
  ``nuav2 convert av2`` (the CLI) in native mode (every 10 Hz sweep a keyframe);
- ``camera_less_db``: the same log with its camera folders removed, converted as
  ``nuav2 convert --allow-missing-cameras`` does (LIDAR_TOP only).

Images are 1/16 of AV2's size and the lidar has 16 rays per beam: a few seconds of CPU in all.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from e2e_helpers import convert


@pytest.fixture(scope="session")
def curved_log(tmp_path_factory) -> Path:
    from nuav2.synth import SynthConfig, generate_log

    config = SynthConfig(seconds=0.6, image_scale=1 / 16, lidar_azimuth_steps=16, n_parked=0, n_moving=0,
                         n_pedestrians=0, include_stereo=True, layout="curved", map_margin_m=20.0)
    return generate_log(tmp_path_factory.mktemp("infos_curved") / "av2", seed=2, config=config)


@pytest.fixture(scope="session")
def curved_db(curved_log: Path) -> Path:
    out = curved_log.parents[2] / "db"
    convert(curved_log.parent, out)
    return out


@pytest.fixture(scope="session")
def camera_less_db(curved_log: Path, tmp_path_factory) -> Path:
    base = tmp_path_factory.mktemp("infos_camera_less")
    log_dir = base / "av2" / curved_log.parent.name / curved_log.name
    shutil.copytree(curved_log, log_dir,
                    ignore=lambda d, names: ["cameras"] if Path(d).name == "sensors" else [])
    convert(log_dir.parent, base / "db", "--allow-missing-cameras")
    return base / "db"
