"""Launch sysid_node with its YAML parameter file (standard launch API; real ROS 2 installs).

    ros2 launch sysid_node sysid.launch.py [params_file:=FILE] [output_topic:=/imu/data] ...
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description() -> LaunchDescription:
    default_params = os.path.join(
        get_package_share_directory("sysid_node"), "config", "sysid_node.yaml"
    )
    params_file = LaunchConfiguration("params_file")
    return LaunchDescription(
        [
            DeclareLaunchArgument(
                "params_file", default_value=default_params,
                description="YAML parameter file (sysid_node: ros__parameters: ...)",
            ),
            DeclareLaunchArgument(
                "output_topic", default_value="/vibration", description="response topic"
            ),
            DeclareLaunchArgument(
                "input_topic", default_value="/excitation",
                description="excitation topic ('' = output-only)",
            ),
            DeclareLaunchArgument(
                "use_sim_time", default_value="false", description="use /clock (bag replay)"
            ),
            Node(
                package="sysid_node",
                executable="sysid_node",
                name="sysid_node",
                output="screen",
                emulate_tty=True,
                parameters=[
                    params_file,
                    {
                        "output_topic": LaunchConfiguration("output_topic"),
                        "input_topic": LaunchConfiguration("input_topic"),
                        "use_sim_time": LaunchConfiguration("use_sim_time"),
                    },
                ],
            ),
        ]
    )
