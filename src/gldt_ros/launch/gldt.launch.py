"""Launch the GL-DT graph on a full ROS 2 installation (mirrors the tested ``pipeline`` runner).

``launch``/``launch_ros`` are not on PyPI, so ``pipeline`` is what CI exercises; this file starts
the same five nodes with the same parameter file for users of a full ROS install.
"""

from pathlib import Path

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument, SetEnvironmentVariable
from launch.substitutions import EnvironmentVariable, LaunchConfiguration
from launch_ros.actions import Node

from launch import LaunchDescription

NODES = ("frame_pair_buffer", "mode_scheduler", "global_detector", "local_detector", "jptrack_tracker")


def generate_launch_description() -> LaunchDescription:
    config = Path(get_package_share_directory("gldt_ros")) / "config"
    default_params = str(config / "gldt.yaml")
    params = LaunchConfiguration("params")
    namespace = LaunchConfiguration("namespace")
    return LaunchDescription(
        [
            DeclareLaunchArgument("params", default_value=default_params, description="parameter YAML"),
            DeclareLaunchArgument("namespace", default_value="", description="namespace (one per camera)"),
            # Fast discovery, as in ``pipeline`` (config/fastdds_profile.xml says why); a profile
            # the user already exported wins. frame_pair_buffer swaps it for its large-segment
            # twin itself (gldt_ros.runtime.dds_profile).
            SetEnvironmentVariable(
                "FASTRTPS_DEFAULT_PROFILES_FILE",
                EnvironmentVariable(
                    "FASTRTPS_DEFAULT_PROFILES_FILE", default_value=str(config / "fastdds_profile.xml")
                ),
            ),
            *[
                Node(
                    package="gldt_ros",
                    executable=name,
                    name=name,
                    namespace=namespace,
                    parameters=[params],
                    output="screen",
                )
                for name in NODES
            ],
        ]
    )
