"""What the mixins of one monitor channel share: its attributes, with their types, and what it asks of its host.

A channel is one monitored axis: :class:`.monitor_node.MonitorNode` (a node of its own) or
:class:`.joint_channel.JointChannel` (one joint of :class:`.joint_group.JointGroupNode`). Both are composed of the
mixins of :mod:`.params`, :mod:`.inputs`, :mod:`.state`, :mod:`.worker` and :mod:`.publishing`, which read and write
the attributes declared here. The declarations are annotations only (nothing is set on the class); the methods the
host provides (``get_logger``, ``get_clock``, ...; rclpy's ``Node`` for a monitor node) and those one mixin calls on
another are declared for the type checker only.
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:   # annotations only: the host's (rclpy's) and the pipeline's types
    from rcl_interfaces.msg import ParameterDescriptor
    from rclpy.clock import Clock
    from rclpy.impl.rcutils_logger import RcutilsLogger
    from rclpy.lifecycle import LifecyclePublisher
    from rclpy.parameter import Parameter
    from rclpy.qos import QoSProfile
    from rclpy.qos_overriding_options import QoSOverridingOptions
    from rclpy.subscription import Subscription

    from ..config import MonitorConfig, Param
    from ..core.pipeline import MonitorPipeline, Report
    from .sync import InputSync


class RingStats:
    """Last ``n`` values of a float series (the delays)."""

    def __init__(self, n: int = 1 << 16) -> None:
        self.buf = np.empty(n)
        self.i = 0
        self.full = False

    def extend(self, x: np.ndarray | float) -> None:
        x = np.asarray(x, dtype=float).ravel()[-self.buf.size:]
        n = x.size
        j = self.i + n
        if j <= self.buf.size:
            self.buf[self.i:j] = x
        else:
            k = self.buf.size - self.i
            self.buf[self.i:] = x[:k]
            self.buf[: n - k] = x[k:]
            self.full = True
        self.i = j % self.buf.size
        if j == self.buf.size:
            self.full = True

    def values(self) -> np.ndarray:
        return self.buf if self.full else self.buf[: self.i]


class NotConfiguredError(RuntimeError):
    """A configured channel's part (pipeline, input stage, configuration) was used before configuration."""


class ChannelState:
    """The state of one monitor channel, shared by its mixins (see the module docstring)."""

    # configuration and the running parts (None until configured)
    _table: dict[str, Param]
    lock: threading.RLock
    pipeline: MonitorPipeline | None
    cfg: MonitorConfig | None
    sync: InputSync | None
    signals: tuple[str, ...]
    topics: dict[str, str]              # signal -> label in every message (the resolved topic for a node)
    _subs: list[Any]                    # rclpy Subscription
    _srvs: list[Any]                    # rclpy Service
    _modes_pub: LifecyclePublisher | None
    _modes_stamped_pub: LifecyclePublisher | None
    _diag_pub: LifecyclePublisher | None
    _save_path: str
    _closed: bool
    _stop: threading.Event
    # periods and options of the configuration (_configure_runtime)
    _use_sim_time: bool
    _stale_timeout_s: float
    _publish_period_s: float
    _diag_period_s: float
    _hardware_id: str
    _block_period_s: float
    _block_batch_s: float
    _block_step_due: float
    # statistics (WorkerMixin._reset_stats)
    delays_ms: RingStats
    _delay_cache: tuple[float, float, float]
    _delay_cache_ns: int
    _busy_s: float
    _data_s: float
    _cpu0: tuple[float, float]
    _cpu_fraction: float
    _malformed: dict[str, int]
    _wrong_types: list[str]
    _errors: int
    _last_error: str
    _next_graph_ns: int
    _latest_report: Report | None       # newest pipeline report (worker -> publisher)
    _modes_queue: deque[tuple[float, np.ndarray]]
    _reports_made: int
    _reports_published: int
    _snapshot: tuple[Report | None, np.ndarray | None]
    _push_started_ns: int
    _last_step_ns: int
    node_stalls: int
    node_stall_max_s: float
    worker_stalls: int
    worker_stall_max_s: float
    _clock_pts: list[tuple[int, float]]

    def configured_pipeline(self) -> MonitorPipeline:
        """The pipeline of a configured channel (:class:`NotConfiguredError` before)."""
        if self.pipeline is None:
            raise NotConfiguredError("the monitor is not configured (no pipeline)")
        return self.pipeline

    def configured_sync(self) -> InputSync:
        """The input stage of a configured channel (:class:`NotConfiguredError` before)."""
        if self.sync is None:
            raise NotConfiguredError("the monitor is not configured (no input stage)")
        return self.sync

    def configured_cfg(self) -> MonitorConfig:
        """The configuration of a configured channel (:class:`NotConfiguredError` before)."""
        if self.cfg is None:
            raise NotConfiguredError("the monitor is not configured")
        return self.cfg

    if TYPE_CHECKING:
        # provided by the host: rclpy's Node for MonitorNode, JointChannel's own for a joint
        @property
        def _active(self) -> bool: ...
        @property
        def looking_since_ns(self) -> int: ...
        @property
        def idle_since_ns(self) -> int: ...
        def get_logger(self) -> RcutilsLogger: ...
        def get_clock(self) -> Clock: ...
        def get_fully_qualified_name(self) -> str: ...
        def parameter_value(self, name: str) -> Any: ...

        # a monitor node's own (rclpy Node): declaring parameters, subscribing, the graph (JointGroupNode does
        # this for its joints)
        _parameter_overrides: dict[str, Parameter]
        _parameters: dict[str, Parameter]
        def declare_parameter(self, name: str, value: Any = None, descriptor: ParameterDescriptor | None = None,
                              ignore_override: bool = False) -> Parameter: ...
        def get_parameter(self, name: str) -> Parameter: ...
        def get_parameter_or(self, name: str, alternative_value: Parameter | None = None) -> Parameter: ...
        def resolve_topic_name(self, topic: str, *, only_expand: bool = False) -> str: ...
        def create_subscription(self, msg_type: Any, topic: str, callback: Callable[[Any], None],
                                qos_profile: QoSProfile | int, *, callback_group: Any = None,
                                event_callbacks: Any = None, qos_overriding_options: QoSOverridingOptions | None = None,
                                raw: bool = False) -> Subscription: ...
        def get_topic_names_and_types(self, no_demangle: bool = False) -> list[tuple[str, list[str]]]: ...
        def get_node_names_and_namespaces(self) -> list[tuple[str, str]]: ...

        # one mixin's methods another calls
        def _check_graph(self) -> None: ...
        def _make_sync(self, cfg: MonitorConfig, v: Mapping[str, Any]) -> InputSync: ...
        def _reset_stats(self) -> None: ...
        def _estimator_values(self, rep: Report | None, h: Mapping[str, Any],
                              silent: list[str]) -> dict[str, Any]: ...
        def save_state(self) -> str: ...
        def warn_duplicate_name(self) -> bool: ...
        def _run_worker(self) -> None: ...
        def _run_publisher(self) -> None: ...
