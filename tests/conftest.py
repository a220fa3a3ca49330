"""Shared pytest fixtures: where the real AV2 fixture lives (skips when ../shared is absent)."""

from __future__ import annotations

import os

# Before torch is imported anywhere (see nuav2/__init__.py): passive OpenMP waits.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from pathlib import Path

import pytest

# Plugin modules that some test files also import by name: rewritten like the tests themselves, and no
# "already imported so cannot be rewritten" warning when the import comes first.
pytest.register_assert_rewrite("e2e_support", "test_writer_support")

REPO = Path(__file__).resolve().parent.parent
SHARED_AV2 = REPO.parent / "shared" / "fixtures" / "av2"
FIXTURE_LOG_ID = "adcf7d18-0510-35b0-a2fa-b4cea13a6d76"


@pytest.fixture(scope="session")
def av2_fixture_root() -> Path:
    """The real AV2 fixture directory (log fragment + calibration_rig)."""
    if not (SHARED_AV2 / FIXTURE_LOG_ID).is_dir():
        pytest.skip(f"real AV2 fixture not found at {SHARED_AV2} (../shared is absent in a user's clone)")
    return SHARED_AV2


@pytest.fixture(scope="session")
def av2_fixture_log(av2_fixture_root: Path) -> Path:
    return av2_fixture_root / FIXTURE_LOG_ID


@pytest.fixture(scope="session")
def av2_fixture_calibration(av2_fixture_root: Path) -> Path:
    return av2_fixture_root / "calibration_rig"
