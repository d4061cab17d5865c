"""Test-side ROS 2 helpers for the monitor-node tests (no tests here): a client node in its own context, the node
process."""
from __future__ import annotations

import subprocess
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.srv import GetParameters, SetParameters
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import Trigger

NODE = "additive_rsrivc_monitor"
TOPICS = {"reference": "/reference", "input": "/plant_input", "output": "/plant_output"}
DATA_QOS = QoSProfile(depth=20000, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST)


def start_node(env: dict, params_file: str, *overrides: str, ros_args: tuple[str, ...] = ()) -> subprocess.Popen:
    """rsrivc_monitor with ``-p`` overrides (and extra ROS arguments such as ``-r __ns:=/axis1``). The tests were
    written for /diagnostics at 10 Hz: unless an override sets it, diagnostics_period_s is 0.1 s here."""
    args = ["rsrivc_monitor", "--ros-args", *ros_args, "--params-file", params_file]
    if not any(o.startswith("diagnostics_period_s:=") for o in overrides):
        overrides = (*overrides, "diagnostics_period_s:=0.1")
    for o in overrides:
        args += ["-p", o]
    env = {**env, "PYTHONFAULTHANDLER": "1"}  # a hung node dumps every thread's stack on SIGABRT (stop_node)
    return subprocess.Popen(args, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def stop_node(proc: subprocess.Popen, sig: str = "TERM", timeout: float = 30.0) -> tuple[int, str]:
    proc.send_signal({"TERM": 15, "INT": 2}[sig])
    try:
        out, _ = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.send_signal(6)  # SIGABRT: faulthandler prints the stacks of all threads into the output
        try:
            out, _ = proc.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            out, _ = proc.communicate()
        return -9, out
    return proc.returncode, out


_POINT_TYPES = {6: "<u4", 8: "<f8"}     # sensor_msgs/PointField UINT32, FLOAT64


def cloud_table(msg: PointCloud2) -> np.ndarray:
    """A PointCloud2 as a numpy structured array built from its own field descriptions (names, types, offsets)."""
    assert not msg.is_bigendian and msg.height == 1 and msg.row_step == msg.point_step * msg.width
    dtype = np.dtype({"names": [f.name for f in msg.fields], "formats": [_POINT_TYPES[f.datatype] for f in msg.fields],
                      "offsets": [f.offset for f in msg.fields], "itemsize": msg.point_step})
    return np.frombuffer(bytes(msg.data), dtype=dtype, count=msg.width)


READ_ONLY_SERVICES = ("GetState", "GetParameters", "ListParameters", "DescribeParameters", "GetParameterTypes")
"""Service types whose request may be sent again when its response was lost (it changes nothing)."""


class Client:
    """Publishers for the signals, subscribers to /diagnostics and ~/modes, service/parameter calls."""

    def __init__(self, domain_id: int, msg_type, node: str = NODE, ns: str = "") -> None:
        """``ns``: the monitor's namespace without slashes ('' = root); topics, services and status names follow."""
        self.ctx = Context()
        rclpy.init(context=self.ctx, domain_id=domain_id)
        self.node = rclpy.create_node("rsrivc_test_client", context=self.ctx)
        base = f"/{ns}" if ns else ""
        self.pubs = {s: self.node.create_publisher(msg_type, base + t, DATA_QOS) for s, t in TOPICS.items()}
        self.diags: list[DiagnosticArray] = []
        self.modes: list[Float64MultiArray] = []
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self.diags.append, 100)
        self.node.create_subscription(Float64MultiArray, f"{base}/{node}/modes", self.modes.append, 100)
        self.stamped: list[PointCloud2] = []
        self.node.create_subscription(PointCloud2, f"{base}/{node}/modes_stamped", self.stamped.append, 100)
        self.target = f"{ns}/{node}" if ns else node
        self._clients: dict[str, Any] = {}
        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.ex.add_node(self.node)
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self) -> None:
        try:
            while self.ctx.ok():
                self.ex.spin_once(timeout_sec=0.05)
        except Exception:  # noqa: BLE001 - context shut down while spinning
            pass

    @staticmethod
    def _within(pred: Callable[[], bool], timeout: float) -> bool:
        t_end = time.monotonic() + timeout
        while time.monotonic() < t_end:
            if pred():
                return True
            time.sleep(0.05)
        return False

    def wait_for(self, pred: Callable[[], bool], timeout: float, what: str) -> None:
        if not self._within(pred, timeout):
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")

    def wait_matched(self, timeout: float = 30.0) -> None:
        self.wait_for(lambda: all(p.get_subscription_count() > 0 for p in self.pubs.values()), timeout,
                      "the node's subscriptions")

    def status(self, suffix: str) -> dict | None:
        """Latest status named '<node>: <suffix>' as {'level', 'message', 'values'}."""
        for arr in reversed(self.diags):
            for st in arr.status:
                if st.name == f"{self.target}: {suffix}":
                    return {"level": st.level[0] if isinstance(st.level, bytes) else int(st.level),
                            "message": st.message, "values": {kv.key: kv.value for kv in st.values},
                            "keys": [kv.key for kv in st.values], "hardware_id": st.hardware_id}
        return None

    def _call(self, srv_type, name: str, req, timeout: float = 20.0):
        """Call a service of the node; one client per service, kept for the next calls.

        rmw_fastrtps drops a response when the server's response writer has not matched the client's response reader
        within its ``max_blocking_time`` (100 ms; ros2/ros2#1253, ros2/rmw_fastrtps#704): a fresh client on a loaded
        machine can wait forever (CI, 2026-11-27: ``get_state`` of a node just started). A kept client is matched after
        its first answer, and a read-only request whose response was lost is sent once more."""
        cli = self._clients.get(name)
        if cli is None:
            cli = self._clients[name] = self.node.create_client(srv_type, name)
        if not cli.wait_for_service(timeout_sec=timeout):
            raise AssertionError(f"service {name} not available")
        attempts = 2 if srv_type.__name__ in READ_ONLY_SERVICES else 1
        for _ in range(attempts):
            fut = cli.call_async(req)
            if self._within(fut.done, timeout):
                return fut.result()
            cli.remove_pending_request(fut)
        raise AssertionError(f"timed out after {timeout} s waiting for response of {name} ({attempts} request(s))")

    def trigger(self, name: str):
        return self._call(Trigger, f"/{self.target}/{name}", Trigger.Request())

    def set_params(self, params: list[Parameter]):
        req = SetParameters.Request()
        req.parameters = [p.to_parameter_msg() for p in params]
        return self._call(SetParameters, f"/{self.target}/set_parameters", req).results

    def set_raw(self, msg: ParameterMsg):
        req = SetParameters.Request()
        req.parameters = [msg]
        return self._call(SetParameters, f"/{self.target}/set_parameters", req).results

    def get_params(self, names: list[str]) -> list:
        req = GetParameters.Request()
        req.names = names
        return self._call(GetParameters, f"/{self.target}/get_parameters", req).values

    def close(self) -> None:
        rclpy.try_shutdown(context=self.ctx)
        self.thread.join(timeout=5.0)
        self.node.destroy_node()
