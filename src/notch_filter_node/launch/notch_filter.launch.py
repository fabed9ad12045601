"""Launch sysid_node and notch_filter_node wired together, with one YAML configuration.

    ros2 launch notch_filter_node notch_filter.launch.py [params_file:=FILE] [with_sysid:=true]
        [namespace:=left_wing]

Both nodes read ``params_file`` (each takes its own section: ``/**/sysid_node:`` and
``/**/notch_filter_node:``, which match the nodes in any namespace); the default is the main
job's ``config/adaptive_notch.yaml``, the file ``ros2_ws/demo`` runs, so the launch behaves as
the demo does. sysid_node publishes ``modal_estimate`` from ``vibration`` (and ``excitation``);
notch_filter_node filters ``vibration`` into ``vibration_filtered`` and publishes
``notch_bank``. The names are relative: with ``namespace:=left_wing`` they are
``/left_wing/vibration`` and so on (``/diagnostics`` stays global). Everything else,
``use_sim_time`` included, comes from the YAML. Two wings at once: ``two_wings.launch.py``.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description() -> LaunchDescription:
    default_params = os.path.join(
        get_package_share_directory("notch_filter_node"), "config", "adaptive_notch.yaml"
    )
    params = LaunchConfiguration("params_file")
    ns = LaunchConfiguration("namespace")
    return LaunchDescription([
        DeclareLaunchArgument("params_file", default_value=default_params,
                              description="YAML with sysid_node and notch_filter_node sections"),
        DeclareLaunchArgument("with_sysid", default_value="true",
                              description="also start sysid_node (the estimator)"),
        DeclareLaunchArgument("namespace", default_value="",
                              description="namespace of both nodes and their relative topics"),
        Node(package="sysid_node", executable="sysid_node", name="sysid_node", namespace=ns,
             parameters=[params], output="screen",
             condition=IfCondition(LaunchConfiguration("with_sysid"))),
        Node(package="notch_filter_node", executable="notch_filter_node",
             name="notch_filter_node", namespace=ns, parameters=[params],
             output="screen"),
    ])
