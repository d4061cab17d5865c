"""Launch one rsrivc_joints process that monitors N joints of a robot from its shared JointState topics.

    ros2 launch additive_rsrivc_ros joints.launch.py count:=4
    ros2 launch additive_rsrivc_ros joints.launch.py params_file:=/path/to/arm.yaml joints:=shoulder,elbow

The node subscribes once to ``joint_commands`` and once to ``joint_states`` (relative names: remap with
``-r``/``remappings``, or set ``reference.topic`` ... in the params file) and runs one monitor per joint, each with its
own section of the params file (``<joint>.modes`` ...), its ``/diagnostics`` statuses ``<node>/<joint>: ...`` and
``~/<joint>/modes``. Which joints: ``joints:=a,b`` monitors those of the params file's ``joints`` list (the node's
parameter ``monitor_joints``), ``count:=N`` the first N (``joint_count``; 0: all). The params file's
top-level key is the node's name (``additive_rsrivc_joints:`` or ``/**:``); see config/joints/arm.yaml and
docs/joints.md.
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import LifecycleNode
from launch_ros.parameter_descriptions import ParameterValue

PACKAGE = "additive_rsrivc_ros"
EXECUTABLE = "rsrivc_joints"
DEFAULT_NODE_NAME = "additive_rsrivc_joints"
DEFAULT_PARAMS = "joints/arm.yaml"


def _node(context) -> list[LifecycleNode]:
    """The node, with ``joints`` (comma-separated) and ``count`` turned into its parameters."""
    joints = [j.strip() for j in LaunchConfiguration("joints").perform(context).split(",") if j.strip()]
    overrides = {"use_sim_time": ParameterValue(LaunchConfiguration("use_sim_time"), value_type=bool),
                 "autostart": ParameterValue(LaunchConfiguration("autostart"), value_type=bool),
                 "joint_count": ParameterValue(LaunchConfiguration("count"), value_type=int)}
    if joints:
        overrides["monitor_joints"] = joints
    return [LifecycleNode(
        package=PACKAGE, executable=EXECUTABLE, name=DEFAULT_NODE_NAME, namespace=LaunchConfiguration("namespace"),
        output="screen", parameters=[LaunchConfiguration("params_file"), overrides],
        arguments=["--ros-args", "--log-level", LaunchConfiguration("log_level")])]


def generate_launch_description() -> LaunchDescription:
    """The declared arguments and one ``rsrivc_joints`` lifecycle node for the chosen joints."""
    default_params = os.path.join(get_package_share_directory(PACKAGE), "config", DEFAULT_PARAMS)
    args = [
        DeclareLaunchArgument("params_file", default_value=default_params,
                              description="params YAML: joints, shared values, one section per joint"),
        DeclareLaunchArgument("joints", default_value="",
                              description="names of the params file's joints to monitor, a,b,c (default: all)"),
        DeclareLaunchArgument("count", default_value="0",
                              description="monitor the first N of those joints (0: all)"),
        DeclareLaunchArgument("namespace", default_value="", description="namespace of the node and its topics"),
        DeclareLaunchArgument("use_sim_time", default_value="false", choices=["true", "false"],
                              description="follow /clock (e.g. rsrivc_replay --clock)"),
        DeclareLaunchArgument("autostart", default_value="true", choices=["true", "false"],
                              description="configure and activate the lifecycle node on start"),
        DeclareLaunchArgument("log_level", default_value="info",
                              choices=["debug", "info", "warn", "error", "fatal"], description="logger level"),
    ]
    return LaunchDescription([*args, OpaqueFunction(function=_node)])
