"""A warm spare for node restarts: an interpreter with every node's modules already imported,
waiting to be told which node to become.

Restarting a node from scratch costs an interpreter start and the imports of rclpy, numpy,
OpenCV, onnxruntime and the core before the node even starts DDS discovery, and on a small
machine under load that is a large share of the time the graph goes without tracks. ``pipeline``
keeps one spare while it supervises the graph and hands it the first node that dies
(:class:`gldt_ros.launcher.pipeline.NodeProcesses`). The nodes it can become are the graph's
(:data:`gldt_ros.interface.graph.NODES`).

Protocol: one line on stdin, a JSON list of the node name and its command-line arguments
(``--ros-args ...``); the spare then runs that node's ``main`` as if started with them. End of
input without a line (the pipeline stopped) exits with 0.
"""

from __future__ import annotations

import importlib
import json
import sys
from typing import TextIO

from gldt_ros.interface.graph import NODES


def become_node(request_line: str) -> int:
    """Run the node named in ``request_line`` (see the module docstring) until it stops."""
    try:
        request = json.loads(request_line)
        if not isinstance(request, list):  # unpacking would take a JSON object's keys as the node
            raise TypeError(f"expected a JSON list, got a JSON {type(request).__name__}")
        name, *arguments = request
    except (ValueError, TypeError) as error:
        print(f"[gldt] spare: bad request {request_line.strip()!r}: {error}", flush=True)
        return 2
    if not isinstance(name, str) or name not in NODES or not all(isinstance(a, str) for a in arguments):
        print(
            f"[gldt] spare: bad request {request_line.strip()!r}: expected one of {list(NODES)} and string arguments",
            flush=True,
        )
        return 2
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
