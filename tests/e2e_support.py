"""Databases exactly as ``nuav2 convert`` writes them, built once per test session (no tests here).

Every consumer test runs on these, never on a hand-written table or sidecar:

- ``native_fixture_db``: the real AV2 fixture log (with calibration and blank images at real pose
  times, see ``test_writer_support``) converted in native mode;
- ``synth_log`` / ``native_synth_db`` / ``warp_db``: a small synthetic log (``nuav2 synth``)
  converted natively and by depth warp into the nuScenes rig;
- ``render_db``: a tiny synthetic log reconstructed with the ``fast`` preset and rendered into
  the nuScenes rig at 1/16 scale (the costly one: ~25 s of CPU);
- ``two_run_db``: two synthetic logs from two split directories converted by two runs into one OUT.

Conversions run under umask 022 through the command line (``nuav2.cli.main``).
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from e2e_helpers import FIXTURE_ID, SYNTH_SECONDS, cli, convert, imaged_copy


@pytest.fixture(scope="session")
def fixture_log(av2_fixture_log: Path, av2_fixture_calibration: Path, tmp_path_factory) -> Path:
    """The real fixture log in a ``val`` split dir, with calibration and blank camera images."""
    return imaged_copy(av2_fixture_log, av2_fixture_calibration, tmp_path_factory.mktemp("e2e_src") / "val",
                       FIXTURE_ID)


@pytest.fixture(scope="session")
def native_fixture_db(fixture_log: Path, tmp_path_factory) -> Path:
    return converted(tmp_path_factory, "e2e_native", fixture_log.parent)


def synth(root: Path, seed: int, split: str = "train") -> Path:
    """``nuav2 synth ROOT --seed SEED --split SPLIT``: the log dir."""
    code, stdout, stderr = cli("synth", root, "--seed", seed, "--split", split, "--seconds", SYNTH_SECONDS)
    assert code == 0, stderr
    return Path(json.loads(stdout)["log_dir"])


@pytest.fixture(scope="session")
def synth_log(tmp_path_factory) -> Path:
    return synth(tmp_path_factory.mktemp("e2e_synth"), 3)


def converted(tmp_path_factory, name: str, src: Path, *flags: str) -> Path:
    out = tmp_path_factory.mktemp(name) / "out"
    convert(src, out, *flags)
    return out


@pytest.fixture(scope="session")
def native_synth_db(synth_log: Path, tmp_path_factory) -> Path:
    return converted(tmp_path_factory, "e2e_native_synth", synth_log.parent)


@pytest.fixture(scope="session")
def warp_db(synth_log: Path, tmp_path_factory) -> Path:
    return converted(tmp_path_factory, "e2e_warp", synth_log.parent, "--mode", "warp", "--rig", "nuscenes",
                     "--scale", "0.25")


@pytest.fixture(scope="session")
def truth_db(synth_log: Path, tmp_path_factory) -> Path:
    """The synthetic log's world drawn exactly in the nuScenes rig (the transfer benchmark's oracle)."""
    return converted(tmp_path_factory, "e2e_truth", synth_log.parent, "--mode", "truth", "--rig", "nuscenes",
                     "--scale", "0.25")


@pytest.fixture(scope="session")
def tiny_synth_log(tmp_path_factory) -> Path:
    """Small enough for a CI-sized reconstruction (the test_recon_pipeline log)."""
    from test_recon_pipeline import TINY_LOG

    from nuav2.synth import generate_log

    return generate_log(tmp_path_factory.mktemp("e2e_tiny_synth"), seed=3, config=TINY_LOG)


@pytest.fixture(scope="session")
def render_db(tiny_synth_log: Path, tmp_path_factory) -> Path:
    return converted(tmp_path_factory, "e2e_render", tiny_synth_log.parent, "--mode", "render",
                     "--recon-preset", "fast", "--scale", "0.0625")


@pytest.fixture(scope="session")
def synth_val_log(tmp_path_factory) -> Path:
    """A second synthetic log (another seed: another place and clock), in a ``val`` split dir."""
    return synth(tmp_path_factory.mktemp("e2e_synth_val"), 4, "val")


@pytest.fixture(scope="session")
def two_run_db(synth_log: Path, synth_val_log: Path, tmp_path_factory) -> tuple[Path, list]:
    """(OUT, [summary of run 1, summary of run 2]): the train split converted, then val, into one OUT."""
    out = tmp_path_factory.mktemp("e2e_two_runs") / "out"
    first = convert(synth_log.parent, out)
    second = convert(synth_val_log.parent, out)
    return out, [first, second]
