"""Launch one resonance monitor per axis, each in its own namespace, from one params file.

    ros2 launch additive_rsrivc_ros multi_axis.launch.py                         # /axis1, /axis2
    ros2 launch additive_rsrivc_ros multi_axis.launch.py axes:=axis1,axis2,axis3 params_file:=/path/to/axes.yaml

``axes``: the namespaces, comma-separated (default ``axis1,axis2``); one ``rsrivc_monitor`` lifecycle node is started
in each. Each monitor subscribes to its own ``/<axis>/reference``, ``/<axis>/plant_input``, ``/<axis>/plant_output``
(relative topic names in the params file) and publishes ``/<axis>/additive_rsrivc_monitor/modes`` and its
``/diagnostics`` statuses under its own node name (``<axis>/additive_rsrivc_monitor: mode 1`` ...), so a fault of one
axis never shows under another. The default params file (config/two_axes.yaml) shares the plant settings under
``/**/additive_rsrivc_monitor:`` (every axis) and overrides one axis under ``/axis2/additive_rsrivc_monitor:``
(rcl's rules for params-file keys); an axis without a section of its own runs on the shared settings.

``aggregator:=true`` also starts diagnostic_aggregator's ``aggregator_node`` with one branch per axis
(``Resonance monitor/<axis>``, additive_rsrivc_ros.diagnostics_config; ``modes:=K`` lists each axis's modes 1..K as
expected statuses), the same analyzers config/diagnostic_aggregator.yaml holds for axis1, axis2.
"""
import os
import re

from ament_index_python.packages import get_package_share_directory
from launch import LaunchContext, LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import LifecycleNode, Node
from launch_ros.parameter_descriptions import ParameterValue

PACKAGE = "additive_rsrivc_ros"
EXECUTABLE = "rsrivc_monitor"
DEFAULT_NODE_NAME = "additive_rsrivc_monitor"
AXES = ("axis1", "axis2")
_AXIS = re.compile(r"[A-Za-z][A-Za-z0-9_]*(/[A-Za-z][A-Za-z0-9_]*)*")   # a relative ROS namespace


def axis_names(text: str) -> list[str]:
    """The namespaces of a comma-separated ``axes`` argument (surrounding slashes and blanks ignored); a name that is
    not a valid namespace or that repeats raises ValueError with one line."""
    names = [a.strip().strip("/") for a in text.split(",") if a.strip().strip("/")]
    bad = [a for a in names if not _AXIS.fullmatch(a)]
    if not names or bad:
        raise ValueError(f"axes:={text!r}: give comma-separated namespaces such as axis1,axis2 "
                         f"(invalid: {', '.join(bad) or 'none given'})")
    if len(set(names)) != len(names):
        raise ValueError(f"axes:={text!r}: an axis is named twice")
    return names


def _monitor(axis: str) -> LifecycleNode:
    """One monitor in namespace ``axis`` with the shared launch arguments."""
    return LifecycleNode(
        package=PACKAGE, executable=EXECUTABLE, name=DEFAULT_NODE_NAME, namespace=axis, output="screen",
        parameters=[LaunchConfiguration("params_file"),
                    {"use_sim_time": ParameterValue(LaunchConfiguration("use_sim_time"), value_type=bool),
                     "autostart": ParameterValue(LaunchConfiguration("autostart"), value_type=bool)}],
        ros_arguments=["--log-level", LaunchConfiguration("log_level")],
    )


def _monitors(context: LaunchContext) -> list[Node]:
    """One monitor per name of the ``axes`` argument (and the aggregator with a branch per axis if asked for)."""
    axes = axis_names(LaunchConfiguration("axes").perform(context))
    nodes: list[Node] = [_monitor(axis) for axis in axes]
    if LaunchConfiguration("aggregator").perform(context) == "true":
        from additive_rsrivc_ros.diagnostics_config import AGGREGATOR_NODE, aggregator_params

        modes = int(LaunchConfiguration("modes").perform(context))
        nodes.append(Node(package="diagnostic_aggregator", executable="aggregator_node", name=AGGREGATOR_NODE,
                          output="screen", parameters=[aggregator_params(axes, DEFAULT_NODE_NAME, modes=modes)],
                          ros_arguments=["--log-level", LaunchConfiguration("log_level")]))
    return nodes


def generate_launch_description() -> LaunchDescription:
    """The declared arguments and one ``rsrivc_monitor`` lifecycle node per axis."""
    default_params = os.path.join(get_package_share_directory(PACKAGE), "config", "two_axes.yaml")
    args = [
        DeclareLaunchArgument("axes", default_value=",".join(AXES),
                              description="namespaces of the monitors, comma-separated (one monitor each)"),
        DeclareLaunchArgument("params_file", default_value=default_params,
                              description="params YAML: shared /**/ section, per-axis sections (config/two_axes.yaml)"),
        DeclareLaunchArgument("use_sim_time", default_value="false", choices=["true", "false"],
                              description="follow /clock (e.g. rsrivc_replay --clock)"),
        DeclareLaunchArgument("autostart", default_value="true", choices=["true", "false"],
                              description="configure and activate the lifecycle nodes on start"),
        DeclareLaunchArgument("aggregator", default_value="false", choices=["true", "false"],
                              description="also start diagnostic_aggregator with one branch per axis"),
        DeclareLaunchArgument("modes", default_value="0",
                              description="with aggregator: modes per axis expected on /diagnostics (0: not listed)"),
        DeclareLaunchArgument("log_level", default_value="info",
                              choices=["debug", "info", "warn", "error", "fatal"], description="logger level"),
    ]
    return LaunchDescription([*args, OpaqueFunction(function=_monitors)])
