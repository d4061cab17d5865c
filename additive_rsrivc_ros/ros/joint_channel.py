"""One joint of ``rsrivc_joints``: the monitor's own per-axis machinery, hosted by the group node.

A :class:`JointChannel` is what one ``rsrivc_monitor`` is minus the ROS node: the same mixins (:mod:`.params` runtime
changes, :mod:`.inputs` input stage, :mod:`.state` ``state_file``, :mod:`.worker` steps, :mod:`.publishing`
``~/<joint>/modes`` and ``/diagnostics``) and the one :class:`..core.pipeline.MonitorPipeline` of the joint (its
estimator and fault decision). It borrows the node functions (logger, clock, publishers, services) from the group node
(:mod:`.joint_group`), under the joint's name: statuses ``<node>/<joint>: mode <i>`` and ``<node>/<joint>:
estimator``, topic ``~/<joint>/modes``, services ``~/<joint>/{reset,rebaseline,save_state}``. Its samples come from
the group's shared subscriptions (:mod:`.joint_fanout`) or, with block input, from its own block topic.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Mapping
from typing import Any

from sensor_msgs.msg import PointCloud2
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import Trigger

from ..config import MonitorConfig, param_table
from ..core.pipeline import MonitorPipeline
from .inputs import InputsMixin, signal_names
from .params import ParametersMixin
from .publishing import PublishingMixin
from .state import StateMixin
from .sync import InputSync
from .worker import WorkerMixin


class JointChannel(ParametersMixin, InputsMixin, StateMixin, WorkerMixin, PublishingMixin):
    """One joint's input stage, pipeline, worker step and outputs; see the module docstring."""

    def __init__(self, group: Any, joint: str) -> None:
        self.group = group
        self.joint = joint
        self._table = param_table()
        self.lock = threading.RLock()
        self.pipeline: MonitorPipeline | None = None
        self.cfg: MonitorConfig | None = None
        self.sync: InputSync | None = None
        self.signals: tuple[str, ...] = ()
        self.topics: dict[str, str] = {}          # signal -> label (topic, joint and field) in every message
        self.topic_of: dict[str, str] = {}        # signal -> resolved topic (graph check)
        self._modes_pub = None
        self._modes_stamped_pub = None
        self._diag_pub = None
        self._srvs: list[Any] = []
        self._save_path = ""
        self._closed = False
        self._logger = group.get_logger().get_child(joint)
        self.cpu_s = 0.0                          # thread CPU of this joint's worker steps
        self._reset_stats()

    # ------------------------------------------------------------------------ what the mixins ask of a node
    @property
    def _active(self) -> bool:
        return self.group._active

    @property
    def looking_since_ns(self) -> int:
        return self.group.looking_since_ns

    @property
    def idle_since_ns(self) -> int:
        return self.group.idle_since_ns

    def get_logger(self) -> Any:
        return self._logger

    def get_clock(self) -> Any:
        return self.group.get_clock()

    def get_fully_qualified_name(self) -> str:
        """``/<ns>/<node>/<joint>``: its statuses are ``<ns>/<node>/<joint>: ...``."""
        return f"{self.group.get_fully_qualified_name()}/{self.joint}"

    def parameter_value(self, name: str) -> Any:
        """The joint's effective value (its own, else the shared one); ``use_sim_time`` is the node's."""
        if name == "use_sim_time":
            return self.group.get_parameter(name).value
        return self.group.joint_values(self.joint)[name]

    def _check_graph(self) -> None:
        """A topic of this joint carrying another message type: name the topic and both types (the node's graph,
        read once a second for all joints)."""
        found = self.group.graph()
        wrong = []
        for s in self.signals:
            want = "std_msgs/msg/Float64MultiArray" if s == "block" else self.configured_cfg().signals[s].type
            topic = self.topic_of[s]
            others = [t for t in found.get(topic, []) if t != want]
            if others:
                wrong.append(f"topic {topic} ({self.joint} {s}) carries {', '.join(others)} but {want} is expected")
        if wrong and wrong != self._wrong_types:
            for w in wrong:
                self.get_logger().error(f"wrong message type: {w}")
        self._wrong_types = wrong

    # ------------------------------------------------------------------------ lifecycle (called by the group)
    def configure(self, cfg: MonitorConfig, values: Mapping[str, Any], topic_of: Mapping[str, str]) -> None:
        """Restore or build the pipeline, name the signals, build the input stage (PipelineError/ValueError)."""
        if cfg.block_input:
            cfg = cfg.with_block_input()
        self.cfg = cfg
        pipeline = self._restore(cfg, values["state_file"])
        self.pipeline = pipeline or MonitorPipeline(cfg)
        self.signals = signal_names(cfg)
        self.topic_of = dict(topic_of)
        self.topics = {s: topic_of[s] if s == "block" else
                       f"{topic_of[s]}[{cfg.signals[s].joint}].{cfg.signals[s].field}" for s in self.signals}
        self._configure_runtime(cfg, dict(values))

    def create_outputs(self, diag_pub: Any) -> None:
        """``~/<joint>/modes`` (and ``~/<joint>/modes_stamped``), the shared /diagnostics publisher and the joint's
        services."""
        node, j = self.group, self.joint
        self._modes_pub = node.create_lifecycle_publisher(Float64MultiArray, f"~/{j}/modes", 10)
        self._modes_stamped_pub = node.create_lifecycle_publisher(PointCloud2, f"~/{j}/modes_stamped", 10)
        self._diag_pub = diag_pub
        self._srvs = [node.create_service(Trigger, f"~/{j}/{name}", srv)
                      for name, srv in (("reset", self._srv_reset), ("rebaseline", self._srv_rebaseline),
                                        ("save_state", self._srv_save))]

    def destroy_outputs(self) -> None:
        node = self.group
        for s in self._srvs:
            node.destroy_service(s)
        for pub in (self._modes_pub, self._modes_stamped_pub):
            if pub is not None:
                node.destroy_lifecycle_publisher(pub)
        self._srvs, self._modes_pub, self._modes_stamped_pub, self._diag_pub = [], None, None, None
        self.pipeline = self.sync = None

    def guarded_step(self) -> None:
        """:meth:`WorkerMixin.guarded_step`, with the thread CPU it took added to this joint's ``cpu_s``."""
        c0 = time.thread_time()
        try:
            WorkerMixin.guarded_step(self)
        finally:
            self.cpu_s += time.thread_time() - c0

    def _estimator_values(self, rep: Any, h: Mapping[str, Any], silent: list[str]) -> dict[str, Any]:
        """The monitor's estimator values plus ``joint``, ``joint_cpu_s`` (thread CPU of this joint's worker steps
        since the node was activated) and ``joint_cpu_fraction`` (that per wall second; the whole process's is
        ``cpu_fraction``, which includes receiving and converting the shared messages)."""
        out = super()._estimator_values(rep, h, silent)
        wall = time.monotonic() - self.group.active_since
        out["joint"] = self.joint
        out["joint_cpu_s"] = float(self.cpu_s)
        out["joint_cpu_fraction"] = self.cpu_s / wall if wall > 0 else float("nan")
        return out

    def close(self) -> None:
        """Save the state once (shutdown)."""
        if not self._closed:
            self._closed = True
            self.save_state()
