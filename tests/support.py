"""Paths and helpers the test folders share (``pythonpath = tests`` in pyproject.toml).

Fixtures live in ``conftest.py``; this module holds what tests need at import time (module
constants, ``parametrize`` lists), so no test recomputes the repository's layout itself.
"""

from __future__ import annotations

import os
import random
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]
BAGS = REPO_ROOT / "bags"
REAL_BAG = BAGS / "halmstad_v_drone_001"
SYNTH_BAG = BAGS / "synth_1080p_multi_uav"
CORE_SRC = REPO_ROOT / "src" / "gldt_core"
CONFIGS = CORE_SRC / "configs"
MSG_DIR = REPO_ROOT / "msg_defs" / "gldt_msgs" / "msg"
#: The real Halmstad clips beside the checkout (``../shared``); ``GLDT_HALMSTAD`` overrides.
HALMSTAD = Path(os.environ.get("GLDT_HALMSTAD", REPO_ROOT.parent / "shared" / "data" / "halmstad-visible"))

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
