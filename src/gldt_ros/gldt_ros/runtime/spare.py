"""A warm spare for node restarts: an interpreter with every node's modules already imported,
waiting to be told which node (or group of nodes) to become.

Restarting a node from scratch costs an interpreter start and the imports of rclpy, numpy,
OpenCV, onnxruntime and the core before the node even starts DDS discovery, and on a small
machine under load that is a large share of the time the graph goes without tracks. ``pipeline``
keeps one spare while it supervises the graph and hands it the first node process that dies
(:class:`gldt_ros.launcher.pipeline.NodeProcesses`). The nodes it can become are the graph's
(:data:`gldt_ros.interface.graph.NODES`).

Protocol: one line on stdin, the JSON list of a node group (:mod:`gldt_ros.runtime.node_group`:
one ``[node, arguments...]`` list per node); the spare then runs a lone node's ``main`` as if
started with its arguments, or hosts the group. End of input without a line (the pipeline
stopped) exits with 0.
"""

from __future__ import annotations

import importlib
import sys
from typing import TextIO

from gldt_ros.interface.graph import NODES
from gldt_ros.runtime.node_group import BAD_GROUP_EXIT, parse_group, run_group


def become_node(request_line: str) -> int:
    """Run the node or nodes named in ``request_line`` (see the module docstring) until they stop."""
    try:
        group = parse_group(request_line)
    except ValueError as error:
        print(f"[gldt] spare: bad request {request_line.strip()!r}: {error}", flush=True)
        return BAD_GROUP_EXIT
    if len(group) > 1:
        return run_group(group)
    name, arguments = group[0]
    module = importlib.import_module(NODES[name])
    sys.argv = [module.__name__, *arguments]  # rclpy.init reads the ROS arguments from sys.argv
    return int(module.main())


def main(stdin: TextIO | None = None) -> int:
    import onnxruntime  # noqa: F401  (the detectors import it only when they open a model)

    for module in NODES.values():
        importlib.import_module(module)
    line = (stdin or sys.stdin).readline()
    if not line:
        return 0
    return become_node(line)


if __name__ == "__main__":
    sys.exit(main())
