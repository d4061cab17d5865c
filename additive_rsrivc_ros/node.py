"""``rsrivc_monitor``: entry point of the ROS 2 lifecycle node (:class:`.ros.monitor_node.MonitorNode`).

Handles ``--help`` and argument errors before anything of ROS is imported, then configures and activates the node
(``autostart``) and spins it until SIGINT/SIGTERM, whose handlers only set a flag (:class:`.signal_stop.SignalStop`):
the spin loop returns within one ``spin_once`` timeout and the node saves its state once. Topics, parameters and
services: docs/INTERFACE.md. Float64 topics are paired by arrival order (:mod:`.ros.sync`; in closed loop verified by
the controller invariant in the pipeline), JointState topics by header stamp, block input by the controller's index
(:mod:`.ros.blocks`). Float64 carries no sequence number: in open loop a message lost on one topic while all keep
streaming shows only when the topics go quiet, so use stamped or block input there, and give the controller's publishers
a RELIABLE history deep enough for the longest stall. Input queues are bounded, arrival rates checked against
``loop_rate_hz``, and the node's own stalls are told from input pauses.
"""

from __future__ import annotations

import sys
import threading
import time

from .process_exit import console_entry
from .signal_stop import SignalStop

_STOP_REQUESTED = SignalStop()  # set by SIGINT/SIGTERM; takes no lock (see .signal_stop: Event.set can deadlock there)


# The console script imports this module first: take over SIGINT/SIGTERM before anything slow is imported (a
# signal during the imports would otherwise end in a KeyboardInterrupt traceback). Only for rsrivc_monitor itself.
# rclpy's own handlers end in an asynchronous ``KeyboardInterrupt``; raised inside a ``with lock:`` it can leave the
# lock held (measured: a SIGINT during activation deadlocked the shutdown), so rclpy is initialised without them.
if sys.argv and sys.argv[0].rsplit("/", 1)[-1] == "rsrivc_monitor" and threading.current_thread() is \
        threading.main_thread():
    _STOP_REQUESTED.install()

#: how long the stop notice waits for /rosout readers to acknowledge it (they are matched by then)
STOP_NOTICE_WAIT_S = 0.3

USAGE = """usage: rsrivc_monitor [-h] [--ros-args [--params-file FILE.yaml] [-p NAME:=VALUE] [-r __node:=NAME]]

ROS 2 lifecycle node: online closed-loop additive recursive SRIVC of mechanical resonances with fault
diagnosis. Subscribes reference, plant_input, plant_output (relative names: /reference ... in the root
namespace, /<ns>/reference ... under -r __ns:=/<ns>; std_msgs/msg/Float64 or sensor_msgs/msg/JointState) or,
with -p block.topic:=block, Float64MultiArray blocks of rows index, reference, input, output,
publishes /diagnostics and ~/modes, serves ~/reset, ~/rebaseline, ~/save_state (std_srvs/srv/Trigger).
Default node name: additive_rsrivc_monitor. Parameters: see config/template.yaml (the YAML key must match
the node's full name: additive_rsrivc_monitor, /**/additive_rsrivc_monitor, /<ns>/additive_rsrivc_monitor or
/**). QoS per subscription: -p qos_overrides./<ns>/plant_output.subscription.reliability:=best_effort.

example:
  rsrivc_monitor --ros-args --params-file my_plant.yaml
  rsrivc_monitor --ros-args --params-file my_plant.yaml -p use_sim_time:=true -p state_file:=/tmp/s.json
  rsrivc_monitor --ros-args -r __ns:=/axis1 --params-file axes.yaml -r plant_output:=/axis1/encoder
"""


def _own_arguments(args: list[str]) -> int | None:
    """``--help`` (exit 0) and arguments before ``--ros-args`` (exit 2, one line); None: go on."""
    own = args[: args.index("--ros-args")] if "--ros-args" in args else args
    if "-h" in own or "--help" in own:
        print(USAGE)
        return 0
    if own:
        print(f"rsrivc_monitor: unknown argument(s) {' '.join(own)} (ROS arguments go after --ros-args; see --help)",
              file=sys.stderr)
        return 2
    return None


#: the ROS 2 Python packages the node imports (rclpy and the interfaces of ros-jazzy-common-interfaces)
ROS_MODULES = ("rclpy", "std_msgs", "diagnostic_msgs", "sensor_msgs", "std_srvs")
INSTALL_ROS = ("source /opt/ros/jazzy/setup.bash (apt: ros-jazzy-ros-base), or pip install "
               "'additive_rsrivc_ros[ros]' (the ros-jazzy-* wheels)")


def _missing_ros() -> str:
    """One line naming the ROS 2 Python modules the node needs and cannot find and how to get them ('' = found).
    Looked up without importing them; the offline tools (rsrivc_diagnose, ...) need none of them."""
    import importlib.util

    missing = []
    for module in ROS_MODULES:
        try:
            found = importlib.util.find_spec(module) is not None
        except (ImportError, ValueError):
            found = False
        if not found:
            missing.append(module)
    if not missing:
        return ""
    return (f"rsrivc_monitor: ROS 2 Jazzy is not installed for this Python ({sys.executable}: no module "
            f"{', '.join(missing)}): {INSTALL_ROS}; the offline tools rsrivc_diagnose, rsrivc_identify, "
            "rsrivc_simulate need no ROS")


@console_entry
def main(argv: list[str] | None = None) -> int:
    """Console script ``rsrivc_monitor``."""
    args = list(sys.argv[1:] if argv is None else argv)
    code = _own_arguments(args)
    if code is not None:
        return code
    started_ns = time.monotonic_ns()
    _STOP_REQUESTED.install()  # first: a signal at any later moment only sets the flag
    missing = _missing_ros()
    if missing:
        print(missing, file=sys.stderr)
        return 1
    import rclpy
    from rclpy.executors import ExternalShutdownException
    from rclpy.experimental import EventsExecutor
    from rclpy.signals import SignalHandlerOptions

    from .ros.monitor_node import MonitorNode, spin
    from .ros.rosout import one_line_error

    rclpy.init(args=["rsrivc_monitor", *args], signal_handler_options=SignalHandlerOptions.NO)
    node = None
    code = 0
    try:
        node = MonitorNode()
        executor = EventsExecutor()
        executor.add_node(node)
        if node.get_parameter("autostart").value and not _STOP_REQUESTED.is_set():
            node.trigger_configure()
            if node.pipeline is None:       # logged as an error by the node; the process ends: FATAL on /rosout
                print(f"rsrivc_monitor: configuration rejected: {node.config_error}", file=sys.stderr)
                node.last_words("fatal", f"configuration rejected: {node.config_error}")
                return 1
            if not _STOP_REQUESTED.is_set():
                node.trigger_activate()
        if not _STOP_REQUESTED.is_set():
            spin(node, executor, started_ns, _STOP_REQUESTED)
        stopping = f"stopping ({_STOP_REQUESTED.signal_name or 'shutdown'})"
        print(f"rsrivc_monitor: {stopping}", file=sys.stderr)
        node.last_words("info", stopping, wait_s=STOP_NOTICE_WAIT_S)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception as exc:  # noqa: BLE001 - parameter declaration errors etc.: one line, non-zero exit
        print(f"rsrivc_monitor: {one_line_error(exc)}", file=sys.stderr)
        if node is not None:    # (an error in the node's constructor reached /rosout there)
            node.last_words("fatal", one_line_error(exc))
        code = 1
    finally:
        if node is not None:
            try:
                node.close()
            except Exception as exc:  # noqa: BLE001
                print(f"rsrivc_monitor: saving state failed: {exc}", file=sys.stderr)
            node.destroy_node()
        rclpy.try_shutdown()
    return code


if __name__ == "__main__":
    sys.exit(main())
