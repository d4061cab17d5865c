"""One joint of ``rsrivc_joints``: the monitor's own per-axis machinery, hosted by the group node.

A :class:`JointChannel` is what one ``rsrivc_monitor`` is minus the ROS node: the same parts
(:class:`.channel_parts.ChannelParts`: :mod:`.params` runtime changes, :mod:`.inputs` input stage, :mod:`.state`
``state_file``, :mod:`.worker` steps, :mod:`.publishing` ``~/<joint>/modes`` and ``/diagnostics``) and the one
:class:`..core.pipeline.MonitorPipeline` of the joint (its estimator and fault decision). It borrows the node functions
(logger, clock, publishers, services) from the group node (:mod:`.joint_group`), under the joint's name: statuses
``<node>/<joint>: mode <i>`` and ``<node>/<joint>: estimator``, topic ``~/<joint>/modes``, services
``~/<joint>/{reset,rebaseline,save_state}``. Its samples come from the group's shared subscriptions
(:mod:`.joint_fanout`) or, with block input, from its own block topic.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import Any, Protocol

from rclpy.clock import Clock
from rclpy.impl.rcutils_logger import RcutilsLogger
from rclpy.parameter import Parameter
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import Trigger

from ..config import MonitorConfig, param_table
from .channel import Activity, ChannelContext
from .channel_parts import ChannelParts
from .inputs import note_wrong_types


class JointHost(Protocol):
    """What a joint channel uses of its group node (:class:`.joint_group.JointGroupNode`): its activity, the joints'
    effective parameters, the graph, and the node functions it borrows."""

    activity: Activity
    active_since: float

    def joint_values(self, joint: str, changes: dict[str, Any] | None = None) -> dict[str, Any]: ...
    def graph(self) -> dict[str, list[str]]: ...
    def get_fully_qualified_name(self) -> str: ...
    def get_logger(self) -> RcutilsLogger: ...
    def get_clock(self) -> Clock: ...
    def get_parameter(self, name: str) -> Parameter: ...
    def create_lifecycle_publisher(self, *args: Any, **kwargs: Any) -> Any: ...
    def create_service(self, *args: Any, **kwargs: Any) -> Any: ...
    def destroy_service(self, *args: Any, **kwargs: Any) -> Any: ...
    def destroy_lifecycle_publisher(self, *args: Any, **kwargs: Any) -> Any: ...


class JointChannel:
    """One joint's parts (input stage, pipeline, worker step, outputs); see the module docstring."""

    def __init__(self, group: JointHost, joint: str) -> None:
        self.group = group
        self.joint = joint
        ctx = ChannelContext(f"{group.get_fully_qualified_name()}/{joint}", group.get_logger().get_child(joint),
                             group.get_clock(), self._parameter_value, group.activity)
        self.parts = ChannelParts(ctx, param_table(), check_graph=self._check_graph, extra_values=self._joint_values)
        self.topic_of: dict[str, str] = {}        # signal -> resolved topic (graph check)
        self._srvs: list[Any] = []
        self._closed = False
        self.cpu_s = 0.0                          # thread CPU of this joint's worker steps

    def _parameter_value(self, name: str) -> Any:
        """The joint's effective value (its own, else the shared one); ``use_sim_time`` is the node's."""
        if name == "use_sim_time":
            return self.group.get_parameter(name).value
        return self.group.joint_values(self.joint)[name]

    def _check_graph(self) -> None:
        """A topic of this joint carrying another message type: name the topic and both types (the node's graph,
        read once a second for all joints)."""
        found = self.group.graph()
        wrong = []
        core = self.parts.core
        for s in core.signals:
            want = "std_msgs/msg/Float64MultiArray" if s == "block" else core.configured_cfg().signals[s].type
            topic = self.topic_of[s]
            others = [t for t in found.get(topic, []) if t != want]
            if others:
                wrong.append(f"topic {topic} ({self.joint} {s}) carries {', '.join(others)} but {want} is expected")
        note_wrong_types(self.parts.stats, self.parts.ctx, wrong)

    # ------------------------------------------------------------------------ lifecycle (called by the group)
    def configure(self, cfg: MonitorConfig, values: Mapping[str, Any], topic_of: Mapping[str, str]) -> None:
        """Restore or build the pipeline, name the signals, build the input stage (PipelineError/ValueError)."""
        if cfg.block_input:
            cfg = cfg.with_block_input()
        parts = self.parts
        parts.build_pipeline(cfg, values["state_file"])
        self.topic_of = dict(topic_of)
        parts.core.topics = {s: topic_of[s] if s == "block" else
                             f"{topic_of[s]}[{cfg.signals[s].joint}].{cfg.signals[s].field}"
                             for s in parts.core.signals}
        parts.configure_runtime(cfg, dict(values))

    def create_outputs(self, diag_pub: Any) -> None:
        """``~/<joint>/modes`` (and ``~/<joint>/modes_stamped``), the shared /diagnostics publisher and the joint's
        services."""
        node, j, out, state = self.group, self.joint, self.parts.outputs, self.parts.state
        out.modes = node.create_lifecycle_publisher(Float64MultiArray, f"~/{j}/modes", 10)
        out.modes_stamped = node.create_lifecycle_publisher(PointCloud2, f"~/{j}/modes_stamped", 10)
        out.diagnostics = diag_pub
        self._srvs = [node.create_service(Trigger, f"~/{j}/{name}", srv)
                      for name, srv in (("reset", state.srv_reset), ("rebaseline", state.srv_rebaseline),
                                        ("save_state", state.srv_save))]

    def destroy_outputs(self) -> None:
        node, out = self.group, self.parts.outputs
        for s in self._srvs:
            node.destroy_service(s)
        for pub in (out.modes, out.modes_stamped):
            if pub is not None:
                node.destroy_lifecycle_publisher(pub)
        self._srvs, out.modes, out.modes_stamped, out.diagnostics = [], None, None, None
        self.parts.unconfigure()

    def guarded_step(self) -> None:
        """:meth:`.worker.Worker.guarded_step`, with the thread CPU it took added to this joint's ``cpu_s``."""
        c0 = time.thread_time()
        try:
            self.parts.worker.guarded_step()
        finally:
            self.cpu_s += time.thread_time() - c0

    def _joint_values(self) -> dict[str, Any]:
        """Estimator values of a joint: ``joint``, ``joint_cpu_s`` (thread CPU of this joint's worker steps since the
        node was activated) and ``joint_cpu_fraction`` (that per wall second; the whole process's is
        ``cpu_fraction``, which includes receiving and converting the shared messages)."""
        wall = time.monotonic() - self.group.active_since
        return {"joint": self.joint, "joint_cpu_s": float(self.cpu_s),
                "joint_cpu_fraction": self.cpu_s / wall if wall > 0 else float("nan")}

    def save_state(self) -> str:
        return self.parts.state.save_state()

    def close(self) -> None:
        """Save the state once (shutdown)."""
        if not self._closed:
            self._closed = True
            self.save_state()
