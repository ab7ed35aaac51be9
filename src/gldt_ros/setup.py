"""ament_python package ``gldt_ros``: executables land in ``lib/gldt_ros`` for ``ros2 run``."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "gldt_ros"

#: One executable per node, plus the graph runner and the example planner-side subscriber.
EXECUTABLES = {
    "frame_pair_buffer": "gldt_ros.nodes.frame_pair_buffer:main",
    "global_detector": "gldt_ros.nodes.global_detector:main",
    "local_detector": "gldt_ros.nodes.local_detector:main",
    "mode_scheduler": "gldt_ros.nodes.mode_scheduler:main",
    "jptrack_tracker": "gldt_ros.nodes.jptrack_tracker:main",
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
        (f"share/{PACKAGE}/config", glob("config/*.yaml") + glob("config/*.xml")),
        (f"share/{PACKAGE}/launch", glob("launch/*.py")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="GL-DT maintainers",
    maintainer_email="maintainers@gldt.dev",
    description="GL-DT ROS 2 node graph over gldt_core",
    license="Apache-2.0",
    entry_points={"console_scripts": [f"{name} = {target}" for name, target in EXECUTABLES.items()]},
)
