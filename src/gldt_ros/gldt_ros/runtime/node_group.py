"""A process that hosts several of the graph's nodes on one executor.

``pipeline --processes grouped`` (:data:`gldt_ros.interface.graph.PROCESS_LAYOUTS`) starts the
nodes that pass a message on every frame in one process: a message between them is still a DDS
message (any other process can subscribe to it), but it crosses no process boundary and wakes no
other process. Each node keeps its own name, parameters, diagnostics and heartbeat.

Usage: ``python -m gldt_ros.runtime.node_group GROUP``, where ``GROUP`` is a JSON list with one
list per node, the node's name then its own command-line arguments (``--ros-args ...``, as its
executable would take them): ``[["frame_pair_buffer", "--ros-args", "--params-file", "gldt.yaml"],
["mode_scheduler", "--ros-args", ...]]``. The warm spare (:mod:`gldt_ros.runtime.spare`) takes the
same list to become a group, or a single node.
"""

from __future__ import annotations

import functools
import importlib
import json
import sys
from collections.abc import Sequence

from gldt_ros.interface.graph import NODES

#: Exit status of a group that was described wrongly (the nodes never started).
BAD_GROUP_EXIT = 2


def parse_group(text: str) -> list[tuple[str, list[str]]]:
    """``[(node name, its arguments), ...]`` from a group's JSON (module docstring); a
    ``ValueError`` naming what is wrong otherwise."""
    try:
        group = json.loads(text)
    except ValueError as error:
        raise ValueError(f"not JSON: {error}") from None
    if not isinstance(group, list) or not group:
        raise ValueError("expected a non-empty JSON list of [node, arguments...] lists")
    parsed: list[tuple[str, list[str]]] = []
    for entry in group:
        if not isinstance(entry, list) or not entry:
            raise ValueError(f"expected a [node, arguments...] list, got {json.dumps(entry)}")
        name, *arguments = entry
        if not isinstance(name, str) or name not in NODES:
            raise ValueError(f"{json.dumps(name)}: expected one of {list(NODES)}")
        if not all(isinstance(argument, str) for argument in arguments):
            raise ValueError(f"{name}: expected string arguments")
        if any(name == seen for seen, _ in parsed):
            raise ValueError(f"{name} is named twice")
        parsed.append((name, list(arguments)))
    return parsed


def group_json(group: Sequence[tuple[str, Sequence[str]]]) -> str:
    """The JSON :func:`parse_group` reads."""
    return json.dumps([[name, *arguments] for name, arguments in group])


def run_group(group: Sequence[tuple[str, Sequence[str]]]) -> int:
    """Run the nodes of ``group`` in this process until they stop (exit status as a node's)."""
    from gldt_ros.runtime.node_base import run_nodes

    modules = [importlib.import_module(NODES[name]) for name, _ in group]
    factories = [
        functools.partial(module.create_node, cli_args=list(arguments))
        for module, (_, arguments) in zip(modules, group)
    ]
    publishes_frames = any(getattr(module, "PUBLISHES_FRAMES", False) for module in modules)
    return run_nodes(factories, args=[], publishes_frames=publishes_frames)


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if len(argv) != 1:
        print("[gldt] node_group: expected one argument, the group's JSON list", flush=True)
        return BAD_GROUP_EXIT
    try:
        group = parse_group(argv[0])
    except ValueError as error:
        print(f"[gldt] node_group: bad group {argv[0]!r}: {error}", flush=True)
        return BAD_GROUP_EXIT
    return run_group(group)


if __name__ == "__main__":
    sys.exit(main())
