"""``rsrivc_joints``: entry point of the multi-joint lifecycle node (:class:`.ros.joint_group.JointGroupNode`).

As ``rsrivc_monitor`` (:mod:`.node`): ``--help`` and argument errors before anything of ROS is imported; SIGINT and
SIGTERM only set a flag; configure and activate (``autostart``), spin until stopped, save every joint's state once.
"""

from __future__ import annotations

import sys
import threading
import time

from .process_exit import console_entry
from .signal_stop import SignalStop

_STOP_REQUESTED = SignalStop()

if sys.argv and sys.argv[0].rsplit("/", 1)[-1] == "rsrivc_joints" and threading.current_thread() is \
        threading.main_thread():
    _STOP_REQUESTED.install()

USAGE = """usage: rsrivc_joints [-h] [--ros-args [--params-file FILE.yaml] [-p NAME:=VALUE] [-r __node:=NAME]]

ROS 2 lifecycle node: one process monitors the resonances of N joints (online closed-loop additive recursive
SRIVC with fault diagnosis per joint) from the shared multi-joint topics a robot publishes. Subscribes once to
joint_commands (reference: position) and joint_states (input: effort, output: position), sensor_msgs/msg/JointState,
header stamp = sample time; a joint with <joint>.block.topic reads Float64MultiArray blocks instead. Per joint
<joint>: publishes ~/<joint>/modes and the /diagnostics statuses '<node>/<joint>: mode <i>' and
'<node>/<joint>: estimator', serves ~/<joint>/reset, ~/<joint>/rebaseline, ~/<joint>/save_state.
Default node name: additive_rsrivc_joints. Parameters: 'joints: [a, b, ...]', shared values at the top level
(those of rsrivc_monitor, config/template.yaml), a joint's own values under '<joint>.' (docs/joints.md,
config/joints/arm.yaml).

example:
  rsrivc_joints --ros-args --params-file arm.yaml
  rsrivc_joints --ros-args --params-file arm.yaml -p "joints:=[shoulder, elbow]" -r joint_states:=/arm/joint_states
"""


def _own_arguments(args: list[str]) -> int | None:
    own = args[: args.index("--ros-args")] if "--ros-args" in args else args
    if "-h" in own or "--help" in own:
        print(USAGE)
        return 0
    if own:
        print(f"rsrivc_joints: unknown argument(s) {' '.join(own)} (ROS arguments go after --ros-args; see --help)",
              file=sys.stderr)
        return 2
    return None


@console_entry
def main(argv: list[str] | None = None) -> int:
    """Console script ``rsrivc_joints``."""
    args = list(sys.argv[1:] if argv is None else argv)
    code = _own_arguments(args)
    if code is not None:
        return code
    started_ns = time.monotonic_ns()
    _STOP_REQUESTED.install()
    import rclpy
    from rclpy.executors import ExternalShutdownException
    from rclpy.experimental import EventsExecutor
    from rclpy.signals import SignalHandlerOptions

    from .config import ParamError
    from .ros.joint_group import JointGroupNode
    from .ros.monitor_node import spin

    rclpy.init(args=["rsrivc_joints", *args], signal_handler_options=SignalHandlerOptions.NO)
    node = None
    code = 0
    try:
        node = JointGroupNode()
        executor = EventsExecutor()
        executor.add_node(node)
        if node.get_parameter("autostart").value and not _STOP_REQUESTED.is_set():
            node.trigger_configure()
            if not node.channels:
                print(f"rsrivc_joints: configuration rejected: {node.config_error}", file=sys.stderr)
                return 1
            if not _STOP_REQUESTED.is_set():
                node.trigger_activate()
        if not _STOP_REQUESTED.is_set():
            spin(node, executor, started_ns, _STOP_REQUESTED)
        print(f"rsrivc_joints: stopping ({_STOP_REQUESTED.signal_name or 'shutdown'})", file=sys.stderr)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception as exc:  # noqa: BLE001 - parameter declaration errors etc.: one line, non-zero exit
        kind = "" if isinstance(exc, ParamError) else f"{type(exc).__name__}: "
        print(f"rsrivc_joints: {kind}{exc}", file=sys.stderr)
        code = 1
    finally:
        if node is not None:
            try:
                node.close()
            except Exception as exc:  # noqa: BLE001
                print(f"rsrivc_joints: saving state failed: {exc}", file=sys.stderr)
            node.destroy_node()
        rclpy.try_shutdown()
    return code


if __name__ == "__main__":
    sys.exit(main())
