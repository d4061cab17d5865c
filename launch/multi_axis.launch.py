"""Launch two resonance monitors, one per axis, in the namespaces ``axis1`` and ``axis2`` from one params file.

    ros2 launch additive_rsrivc_ros multi_axis.launch.py params_file:=/path/to/axes.yaml

Each monitor subscribes to its own ``/axisN/reference``, ``/axisN/plant_input``, ``/axisN/plant_output`` (relative
topic names in the params file) and publishes ``/axisN/additive_rsrivc_monitor/modes`` and its ``/diagnostics``
statuses under its own node name. The default params file (config/two_axes.yaml) shares the plant settings under
``/**/additive_rsrivc_monitor:`` and overrides per axis under ``/axis1/additive_rsrivc_monitor:`` and
``/axis2/additive_rsrivc_monitor:`` (rcl's rules for params-file keys). More axes: add names to ``AXES``.
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import LifecycleNode
from launch_ros.parameter_descriptions import ParameterValue

PACKAGE = "additive_rsrivc_ros"
EXECUTABLE = "rsrivc_monitor"
DEFAULT_NODE_NAME = "additive_rsrivc_monitor"
AXES = ("axis1", "axis2")


def _monitor(axis: str) -> LifecycleNode:
    """One monitor in namespace ``axis`` with the shared launch arguments."""
    return LifecycleNode(
        package=PACKAGE, executable=EXECUTABLE, name=DEFAULT_NODE_NAME, namespace=axis, output="screen",
        parameters=[LaunchConfiguration("params_file"),
                    {"use_sim_time": ParameterValue(LaunchConfiguration("use_sim_time"), value_type=bool),
                     "autostart": ParameterValue(LaunchConfiguration("autostart"), value_type=bool)}],
        arguments=["--ros-args", "--log-level", LaunchConfiguration("log_level")],
    )


def generate_launch_description() -> LaunchDescription:
    """The declared arguments and one ``rsrivc_monitor`` lifecycle node per axis."""
    default_params = os.path.join(get_package_share_directory(PACKAGE), "config", "two_axes.yaml")
    args = [
        DeclareLaunchArgument("params_file", default_value=default_params,
                              description="params YAML with a section per axis (see config/two_axes.yaml)"),
        DeclareLaunchArgument("use_sim_time", default_value="false", choices=["true", "false"],
                              description="follow /clock (e.g. rsrivc_replay --clock)"),
        DeclareLaunchArgument("autostart", default_value="true", choices=["true", "false"],
                              description="configure and activate the lifecycle nodes on start"),
        DeclareLaunchArgument("log_level", default_value="info",
                              choices=["debug", "info", "warn", "error", "fatal"], description="logger level"),
    ]
    return LaunchDescription([*args, *(_monitor(axis) for axis in AXES)])
