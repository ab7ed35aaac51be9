"""Shared fixtures, and the markers of each test folder.

``core/`` needs neither ROS nor the real clips; ``ros/`` needs the colcon-built workspace and
rclpy (marker ``ros``); ``faults/`` feeds bad input and faults to both (marker ``faults``, plus
``ros`` for the files that start a graph). Run one area with ``make test PYTEST_ARGS="-m ros"``.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from support import HALMSTAD, REPO_ROOT


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        path = Path(str(item.fspath))
        area = path.parent.name
        if area == "ros" or path.name.startswith("test_ros_"):
            item.add_marker(pytest.mark.ros)
        if area == "faults":
            item.add_marker(pytest.mark.faults)


@pytest.fixture(scope="session")
def repo_root() -> Path:
    """The repository root."""
    return REPO_ROOT


@pytest.fixture(scope="session")
def halmstad_dir() -> Path:
    """The real Halmstad clips beside the project; tests that need them skip when absent."""
    if not (HALMSTAD / "videos").is_dir():
        pytest.skip(f"real clips not available at {HALMSTAD} (../shared is not beside this checkout)")
    return HALMSTAD
