"""Launch the GL-DT graph on a full ROS 2 installation (mirrors the tested ``pipeline`` command).

``launch``/``launch_ros`` are not on PyPI, so ``pipeline`` is what CI exercises; this file starts
the same nodes (:data:`gldt_ros.interface.graph.NODES`) with the same parameter file for users of
a full ROS install.
"""

from launch.actions import DeclareLaunchArgument, SetEnvironmentVariable
from launch.launch_description import LaunchDescription
from launch.substitutions import EnvironmentVariable, LaunchConfiguration
from launch_ros.actions import Node

from gldt_ros.interface.graph import NODES, PACKAGE, default_params_file, shipped_config


def generate_launch_description() -> LaunchDescription:
    params = LaunchConfiguration("params")
    namespace = LaunchConfiguration("namespace")
    return LaunchDescription(
        [
            DeclareLaunchArgument("params", default_value=str(default_params_file()), description="parameter YAML"),
            DeclareLaunchArgument("namespace", default_value="", description="namespace (one per camera)"),
            # Fast discovery, as in ``pipeline`` (config/fastdds_profile.xml says why); a profile
            # the user already exported wins. frame_pair_buffer swaps it for its large-segment
            # twin itself (gldt_ros.runtime.dds_profile).
            SetEnvironmentVariable(
                "FASTRTPS_DEFAULT_PROFILES_FILE",
                EnvironmentVariable(
                    "FASTRTPS_DEFAULT_PROFILES_FILE", default_value=str(shipped_config("fastdds_profile.xml"))
                ),
            ),
            *[
                Node(
                    package=PACKAGE,
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
