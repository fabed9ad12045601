"""Launch sysid_node with its YAML parameter file (standard launch API; real ROS 2 installs).

    ros2 launch sysid_node sysid.launch.py [params_file:=FILE] [output_topic:=imu/data]
        [output_type:=Imu] [input_topic:=excitation] [input_type:=SignalSample]
        [use_sim_time:=true] [namespace:=left_wing]

The YAML decides: a topic, type or ``use_sim_time`` argument overrides the file only when it is
given on the command line (or by an including launch file); arguments left out keep the file's
values, or the node's defaults where the file says nothing. ``namespace`` moves the node and its
relative topics (``vibration`` -> ``/left_wing/vibration``).
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue

#: Launch arguments that override a parameter of the file, only when given explicitly:
#: name -> (parameter type, description).
OVERRIDES = {
    "output_topic": (str, "response topic (default: the file's, else 'vibration')"),
    "output_type": (str, "SignalSample | SignalBlock | Imu (default: the file's)"),
    "input_topic": (str, "excitation topic, '' = output-only (default: the file's)"),
    "input_type": (str, "SignalSample | SignalBlock | Imu (default: the file's)"),
    "use_sim_time": (bool, "true = use /clock, e.g. under ros2 bag play --clock "
                           "(default: the file's, else false)"),
}


def generate_launch_description() -> LaunchDescription:
    default_params = os.path.join(
        get_package_share_directory("sysid_node"), "config", "sysid_node.yaml"
    )
    given: set[str] = set()

    def note_given(context, *args, **kwargs):
        # Runs before the declarations below: a configuration that exists now was passed on
        # the command line or by an including launch file, not filled in from a default.
        given.update(n for n in OVERRIDES if n in context.launch_configurations)
        return []

    def make_node(context, *args, **kwargs):
        overrides = {
            n: ParameterValue(LaunchConfiguration(n), value_type=OVERRIDES[n][0])
            for n in sorted(given)
        }
        return [
            Node(
                package="sysid_node",
                executable="sysid_node",
                name="sysid_node",
                namespace=LaunchConfiguration("namespace"),
                output="screen",
                parameters=[LaunchConfiguration("params_file"), overrides],
            )
        ]

    return LaunchDescription(
        [
            OpaqueFunction(function=note_given),
            DeclareLaunchArgument(
                "params_file", default_value=default_params,
                description="YAML parameter file (/**/sysid_node: ros__parameters: ...)",
            ),
            DeclareLaunchArgument(
                "namespace", default_value="",
                description="namespace of the node and its relative topics, e.g. left_wing",
            ),
            *(
                DeclareLaunchArgument(name, default_value="", description=text)
                for name, (_, text) in OVERRIDES.items()
            ),
            OpaqueFunction(function=make_node),
        ]
    )
