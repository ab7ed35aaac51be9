"""Shared test set-up: keep ROS traffic of this run on loopback and in its own DDS domain."""

from __future__ import annotations

import os
import random
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO_ROOT.parent / "shared" / "data" / "halmstad-visible"

# A private domain per test run, so parallel runs (and other sessions) never see each other's
# topics; localhost-only discovery keeps DDS off the network.
os.environ.setdefault("ROS_DOMAIN_ID", str(random.SystemRandom().randint(1, 100)))
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")


@pytest.fixture(scope="session")
def repo_root() -> Path:
    """The repository root."""
    return REPO_ROOT


@pytest.fixture(scope="session")
def halmstad_dir() -> Path:
    """The real Halmstad clips beside the project; tests that need them skip when absent."""
    if not (SHARED_DATA / "videos").is_dir():
        pytest.skip(f"real clips not available at {SHARED_DATA} (../shared is not beside this checkout)")
    return SHARED_DATA
