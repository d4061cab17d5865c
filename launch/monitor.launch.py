"""Launch one resonance monitor (rsrivc_monitor, a lifecycle node).

    ros2 launch additive_rsrivc_ros monitor.launch.py params_file:=/path/to/plant.yaml namespace:=axis1

Arguments: ``params_file`` (default: the installed ``config/beam.yaml``), ``namespace`` (default: none),
``node_name`` (default ``additive_rsrivc_monitor``), ``use_sim_time``, ``autostart`` (configure and activate on
start; ``false`` leaves the node unconfigured for a lifecycle manager), ``log_level``.

The params file is handed to rcl as it is, so its top-level key must match the node's full name. The shipped
files and those ``rsrivc_identify --out-params`` writes use ``/**/additive_rsrivc_monitor:`` (that node name in any
namespace, the root one included); ``/axis1/additive_rsrivc_monitor:`` reaches one namespace only
(config/two_axes.yaml shows both), and a plain ``additive_rsrivc_monitor:`` only the root namespace.
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


def generate_launch_description() -> LaunchDescription:
    """The declared arguments and one ``rsrivc_monitor`` lifecycle node built from them."""
    default_params = os.path.join(get_package_share_directory(PACKAGE), "config", "beam.yaml")
    args = [
        DeclareLaunchArgument("params_file", default_value=default_params,
                              description="monitor params YAML (see config/template.yaml)"),
        DeclareLaunchArgument("namespace", default_value="", description="namespace of the node and its topics"),
        DeclareLaunchArgument("node_name", default_value=DEFAULT_NODE_NAME, description="node name"),
        DeclareLaunchArgument("use_sim_time", default_value="false", choices=["true", "false"],
                              description="follow /clock (e.g. rsrivc_replay --clock)"),
        DeclareLaunchArgument("autostart", default_value="true", choices=["true", "false"],
                              description="configure and activate the lifecycle node on start"),
        DeclareLaunchArgument("log_level", default_value="info",
                              choices=["debug", "info", "warn", "error", "fatal"], description="logger level"),
    ]
    node = LifecycleNode(
        package=PACKAGE, executable=EXECUTABLE, name=LaunchConfiguration("node_name"),
        namespace=LaunchConfiguration("namespace"), output="screen",
        parameters=[LaunchConfiguration("params_file"),
                    {"use_sim_time": ParameterValue(LaunchConfiguration("use_sim_time"), value_type=bool),
                     "autostart": ParameterValue(LaunchConfiguration("autostart"), value_type=bool)}],
        ros_arguments=["--log-level", LaunchConfiguration("log_level")],
    )
    return LaunchDescription([*args, node])
