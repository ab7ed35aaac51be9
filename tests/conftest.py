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


_next_domain = [int(os.environ["ROS_DOMAIN_ID"])]


def isolated_ros_env() -> dict[str, str]:
    """Environment for a ROS subprocess with a DDS domain of its own.

    Each graph a test starts gets a fresh domain, so a straggler of an earlier test (a killed
    node's participant that DDS still remembers) can never talk to it.
    """
    _next_domain[0] = _next_domain[0] % 100 + 1
    env = dict(os.environ)
    env["ROS_DOMAIN_ID"] = str(_next_domain[0])
    return env


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
