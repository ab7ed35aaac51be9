"""Paths and helpers the test folders share (``pythonpath = tests`` in pyproject.toml).

Fixtures live in ``conftest.py``; this module holds what tests need at import time (module
constants, ``parametrize`` lists), so no test recomputes the repository's layout itself.
"""

from __future__ import annotations

import os
import random
import subprocess
import threading
import time
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


#: The installed ``pipeline`` command (``make test`` builds it).
PIPELINE = REPO_ROOT / "install" / "gldt_ros" / "lib" / "gldt_ros" / "pipeline"


class PipelineRun:
    """A ``pipeline`` process started with ``arguments``, whose output lines are collected as they
    come (:attr:`lines`), each also with its arrival time (:attr:`timed`)."""

    def __init__(self, arguments: list[str], env: dict[str, str]) -> None:
        self.process = subprocess.Popen(
            [str(PIPELINE), *arguments], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env
        )
        self.timed: list[tuple[float, str]] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.process.stdout is not None
        for line in self.process.stdout:
            self.timed.append((time.monotonic(), line.rstrip("\n")))

    @property
    def lines(self) -> list[str]:
        return [line for _, line in list(self.timed)]

    @property
    def text(self) -> str:
        return "\n".join(self.lines)

    def with_text(self, fragment: str) -> list[tuple[float, str]]:
        """``(arrival time, line)`` of each line holding ``fragment``."""
        return [(when, line) for when, line in list(self.timed) if fragment in line]

    def wait(self, timeout_s: float) -> int:
        code = self.process.wait(timeout=timeout_s)
        self._reader.join(timeout=5.0)
        return code


def replay_in_lockstep(bag: Path, record: Path, frame_timeout_s: float) -> subprocess.CompletedProcess[str]:
    """``pipeline --bag BAG --lockstep --keep-bag-stamps --record RECORD --frame-timeout S`` to its
    end, on a domain of its own: the recorded tracks carry the bag's stamps and name the frames
    that were answered."""
    return subprocess.run(
        [str(PIPELINE), "--bag", str(bag), "--lockstep", "--keep-bag-stamps", "--record", str(record)]
        + ["--frame-timeout", f"{frame_timeout_s:g}"],
        capture_output=True,
        text=True,
        timeout=600,
        env=isolated_ros_env(),
    )
