"""Fixtures shared by the tests of the ROS package (``gldt_ros`` is imported only when one is used,
so a checkout without the colcon workspace still collects, and skips, these tests)."""

from __future__ import annotations

import argparse
import subprocess
import threading
from collections.abc import Callable, Iterator
from typing import Any

import pytest

ProcessMap = dict[str, subprocess.Popen[bytes]]


@pytest.fixture
def context() -> Iterator[Any]:
    """An rclpy context on a DDS domain of its own (``support.isolated_ros_env``)."""
    import rclpy
    from rclpy.context import Context

    from support import isolated_ros_env

    context = Context()
    rclpy.init(context=context, domain_id=int(isolated_ros_env()["ROS_DOMAIN_ID"]))
    try:
        yield context
    finally:
        rclpy.shutdown(context=context)


@pytest.fixture
def node_processes_of() -> Callable[[ProcessMap], Any]:
    """Builds a ``gldt_ros.launcher.pipeline.NodeProcesses`` that supervises the given stand-in
    processes (name -> process) instead of launching the graph's nodes, to test how it stops them."""
    from gldt_ros.launcher.pipeline import NodeProcesses

    def adopt(processes: ProcessMap) -> NodeProcesses:
        children = object.__new__(NodeProcesses)
        children.args = argparse.Namespace()
        children.processes = processes
        children.groups = tuple((name,) for name in processes)
        children.restarts = {name: 0 for name in processes}
        children.supervising = True
        children.spare = None
        children._segments_due = None
        children._lock = threading.Lock()
        return children

    return adopt
