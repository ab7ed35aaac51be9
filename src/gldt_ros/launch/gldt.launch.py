"""Launch the GL-DT graph on a full ROS 2 installation (mirrors the tested ``pipeline`` runner).

``launch``/``launch_ros`` are not on PyPI, so ``pipeline`` is what CI exercises; this file starts
the same five nodes with the same parameter file for users of a full ROS install.
"""

from pathlib import Path

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

NODES = ("frame_pair_buffer", "mode_scheduler", "global_detector", "local_detector", "jptrack_tracker")


def generate_launch_description() -> LaunchDescription:
    default_params = str(Path(get_package_share_directory("gldt_ros")) / "config" / "gldt.yaml")
    params = LaunchConfiguration("params")
    namespace = LaunchConfiguration("namespace")
    return LaunchDescription(
        [
            DeclareLaunchArgument("params", default_value=default_params, description="parameter YAML"),
            DeclareLaunchArgument("namespace", default_value="", description="namespace (one per camera)"),
            *[
                Node(package="gldt_ros", executable=name, name=name, namespace=namespace, parameters=[params], output="screen")
                for name in NODES
            ],
        ]
    )
