"""Two independent estimator + notch bank pairs, one per wing, from one YAML.

    ros2 launch notch_filter_node two_wings.launch.py [params_file:=FILE]
        [wings:=left_wing,right_wing]

Each wing gets its own namespace (``PushRosNamespace``): ``/left_wing/sysid_node`` reads
``/left_wing/vibration`` and publishes ``/left_wing/modal_estimate``, which only
``/left_wing/notch_filter_node`` follows; the right wing likewise. Both report on the global
``/diagnostics`` under their own names (``left_wing/sysid_node: identification``). The YAML's
``/**/sysid_node:`` and ``/**/notch_filter_node:`` sections apply to both wings.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, GroupAction, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node, PushRosNamespace


def _wings(context, *args, **kwargs):
    params = LaunchConfiguration("params_file")
    names = [w.strip() for w in context.perform_substitution(
        LaunchConfiguration("wings")).split(",") if w.strip()]
    return [
        GroupAction([
            PushRosNamespace(wing),
            Node(package="sysid_node", executable="sysid_node", name="sysid_node",
                 parameters=[params], output="screen"),
            Node(package="notch_filter_node", executable="notch_filter_node",
                 name="notch_filter_node", parameters=[params], output="screen"),
        ])
        for wing in names
    ]


def generate_launch_description() -> LaunchDescription:
    default_params = os.path.join(
        get_package_share_directory("notch_filter_node"), "config", "adaptive_notch.yaml"
    )
    return LaunchDescription([
        DeclareLaunchArgument("params_file", default_value=default_params,
                              description="YAML with /**/sysid_node and /**/notch_filter_node"),
        DeclareLaunchArgument("wings", default_value="left_wing,right_wing",
                              description="comma-separated namespaces, one pair of nodes each"),
        OpaqueFunction(function=_wings),
    ])
