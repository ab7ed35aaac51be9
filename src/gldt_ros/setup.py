"""ament_python package ``gldt_ros``: executables land in ``lib/gldt_ros`` for ``ros2 run``."""

import importlib.util
from pathlib import Path

from setuptools import find_packages, setup

PACKAGE = "gldt_ros"
HERE = Path(__file__).resolve().parent


def graph_nodes() -> dict[str, str]:
    """The graph's nodes (name -> module) from ``gldt_ros/interface/graph.py``, loaded by its path:
    at build time neither rclpy nor the package itself can be imported."""
    spec = importlib.util.spec_from_file_location("gldt_ros_graph", HERE / PACKAGE / "interface" / "graph.py")
    if spec is None or spec.loader is None:
        raise RuntimeError(f"cannot load {PACKAGE}/interface/graph.py from {HERE}")
    graph = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(graph)
    return dict(graph.NODES)


def shipped_files(folder: str, *patterns: str) -> list[str]:
    """The files in ``folder`` that match ``patterns``, relative to this file as setuptools takes
    them; none is a packaging error (the graph cannot start without its configuration)."""
    files = sorted({str(path.relative_to(HERE)) for pattern in patterns for path in (HERE / folder).glob(pattern)})
    if not files:
        raise RuntimeError(f"no {' or '.join(patterns)} files in {HERE / folder}")
    return files


#: One executable per graph node, plus the ``pipeline`` command that starts the graph and the
#: example planner-side subscriber.
EXECUTABLES = {
    **{name: f"{module}:main" for name, module in graph_nodes().items()},
    "threat_monitor": "gldt_ros.examples.threat_monitor:main",
    "pipeline": "gldt_ros.launcher.pipeline:main",
}

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", shipped_files("config", "*.yaml", "*.xml")),
        (f"share/{PACKAGE}/launch", shipped_files("launch", "*.py")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="GL-DT maintainers",
    maintainer_email="maintainers@gldt.dev",
    description="GL-DT ROS 2 node graph over gldt_core",
    license="Apache-2.0",
    entry_points={"console_scripts": [f"{name} = {target}" for name, target in EXECUTABLES.items()]},
)
