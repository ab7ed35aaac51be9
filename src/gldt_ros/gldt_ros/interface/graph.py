"""The GL-DT node graph as a whole: which nodes it has, and the configuration files shipped with it.

Every place that starts, restarts, installs or lists the graph's nodes reads them from
:data:`NODES`: the ``pipeline`` command (:mod:`gldt_ros.launcher.pipeline`) and its replay driver
(:mod:`gldt_ros.launcher.replay`), the warm spare (:mod:`gldt_ros.runtime.spare`), the launch file
(``launch/gldt.launch.py``), ``setup.py`` (one ``ros2 run`` executable per node), the benchmarks and
the tests.

This module imports nothing but the standard library, and ament's index only when asked for a
file, so ``setup.py`` can load it by its path at build time, when neither rclpy nor the package
itself can be imported.
"""

from __future__ import annotations

from pathlib import Path

#: The ROS package the graph's executables, launch file and configuration are installed with.
PACKAGE = "gldt_ros"

#: The graph's nodes in start order: node name (also its executable's name) -> the module that
#: defines it. Each module has ``create_node(cli_args)``, which builds the node in any process,
#: and ``main()``, which runs it as a process of its own.
NODES: dict[str, str] = {
    "frame_pair_buffer": "gldt_ros.nodes.frame_pair_buffer",
    "mode_scheduler": "gldt_ros.nodes.mode_scheduler",
    "global_detector": "gldt_ros.nodes.global_detector",
    "local_detector": "gldt_ros.nodes.local_detector",
    "jptrack_tracker": "gldt_ros.nodes.jptrack_tracker",
}

#: How ``pipeline --processes`` places the nodes in processes: layout -> the groups of nodes that
#: share a process (:mod:`gldt_ros.runtime.node_group`; a group of one is the node's own
#: executable). ``grouped`` (the default) puts every node a LOCAL frame passes through (buffer,
#: scheduler, tracker, local detector) in one process, so the five hops of such a frame after the
#: camera's cost no process switch, and leaves the global detector, which works on a pair for
#: longer than a frame period, in a process of its own, in parallel. ``one-process`` puts all five
#: in one process: the global detector's pair and detections stay in it too, and its model runs on
#: a thread of its own, so the other nodes go on answering frames meanwhile. A group restarts as a
#: whole: a crash of the local detector costs the tracks their ids. ``per-node`` isolates every
#: node. ``python -m gldt_ros.bench.graph --processes LAYOUT`` measures what each costs per frame.
PER_NODE = "per-node"
GROUPED = "grouped"
ONE_PROCESS = "one-process"
PROCESS_LAYOUTS: dict[str, tuple[tuple[str, ...], ...]] = {
    PER_NODE: tuple((name,) for name in NODES),
    GROUPED: (("frame_pair_buffer", "mode_scheduler", "jptrack_tracker", "local_detector"), ("global_detector",)),
    ONE_PROCESS: (tuple(NODES),),
}
#: The layout ``pipeline`` starts when not told otherwise.
DEFAULT_PROCESS_LAYOUT = GROUPED


def group_label(group: tuple[str, ...] | list[str]) -> str:
    """How ``pipeline`` names the process of a group of nodes in what it prints ("a+b+c"; a lone
    node by its own name), and how ``python -m gldt_ros.bench.restart`` finds it there."""
    return "+".join(group)


#: ``header.frame_id`` of the warm-up frame ``pipeline --bag`` sends before the replay: a copy of
#: the bag's first image that runs through every node (first inference, every link's first
#: message) and leaves no state behind. Each node that keeps state across frames starts afresh
#: once it has handled it (the buffer after its decision, the scheduler after planning it, the
#: global detector after its pair, the tracker after answering it), and the recording leaves it out.
WARM_UP_FRAME_ID = "gldt_warm_up"

#: The parameter file of every node, generated from :mod:`gldt_ros.interface.params`.
PARAMS_FILE = "gldt.yaml"


def shipped_config(name: str) -> Path:
    """``share/gldt_ros/config/<name>`` of the installed package, or ``config/<name>`` of the
    package's source folder where ament's index does not know the package (run from source)."""
    try:
        from ament_index_python.packages import get_package_share_directory

        share = Path(get_package_share_directory(PACKAGE))
    except (ImportError, LookupError, OSError):  # no ament index, package not in it, AMENT_PREFIX_PATH unset
        share = Path(__file__).resolve().parents[2]
    return share / "config" / name


def default_params_file() -> Path:
    """The shipped parameter file (:data:`PARAMS_FILE`), which holds every parameter's default."""
    return shipped_config(PARAMS_FILE)
