"""One monitor channel's shared, typed state: what its parts (:mod:`.params`, :mod:`.inputs`, :mod:`.worker`,
:mod:`.publishing`, :mod:`.state`) receive in their constructors.

A channel is one monitored axis: :class:`.monitor_node.MonitorNode` (a node of its own) or
:class:`.joint_channel.JointChannel` (one joint of :class:`.joint_group.JointGroupNode`); both own one
:class:`.channel_parts.ChannelParts`. Here: :class:`ChannelContext` (name, logger, clock, parameters and the host's
:class:`Activity`), :class:`ChannelCore` (configuration, pipeline, input stage, under one lock),
:class:`ChannelSettings` (periods and options), :class:`ChannelStats` (the worker's and the inputs' statistics) and
:class:`Outbox` (reports from the worker to the publisher).
"""

from __future__ import annotations

import math
import threading
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:   # annotations only: the host's (rclpy's) and the pipeline's types
    from rclpy.clock import Clock
    from rclpy.impl.rcutils_logger import RcutilsLogger

    from ..config import MonitorConfig
    from ..core.monitor.pipeline import MonitorPipeline, Report
    from .input_stage import InputStage

MODES_QUEUE = 10_000        # ~/modes messages the publisher may fall behind before the oldest are coalesced (counted)


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


@dataclass
class Activity:
    """What the host node's executor loop (:func:`.monitor_node.spin`) and lifecycle record; one per node (a joint
    channel shares its group's)."""

    active: bool = False          # activated: inputs are taken, outputs published
    idle_since_ns: int = 0        # the executor's last wait without work
    looking_since_ns: int = 0     # start of the executor's current uninterrupted run (0: not yet)


@dataclass(frozen=True)
class ChannelContext:
    """Who a channel is: its fully qualified name (statuses, state file), logger, clock, parameter lookup and the
    host's activity."""

    name: str
    logger: RcutilsLogger
    clock: Clock
    parameter: Callable[[str], Any]
    activity: Activity

    def ros_now_s(self) -> float:
        return self.clock.now().nanoseconds * 1e-9


class ChannelCore:
    """The configured parts of a channel (None until configured), guarded by :attr:`lock`."""

    def __init__(self) -> None:
        self.lock = threading.RLock()
        self.pipeline: MonitorPipeline | None = None
        self.cfg: MonitorConfig | None = None
        self.sync: InputStage | None = None
        self.signals: tuple[str, ...] = ()
        self.topics: dict[str, str] = {}    # signal -> label in every message (the resolved topic for a node)

    def configured_pipeline(self) -> MonitorPipeline:
        """The pipeline of a configured channel (:class:`NotConfiguredError` before)."""
        if self.pipeline is None:
            raise NotConfiguredError("the monitor is not configured (no pipeline)")
        return self.pipeline

    def configured_sync(self) -> InputStage:
        """The input stage of a configured channel (:class:`NotConfiguredError` before)."""
        if self.sync is None:
            raise NotConfiguredError("the monitor is not configured (no input stage)")
        return self.sync

    def configured_cfg(self) -> MonitorConfig:
        """The configuration of a configured channel (:class:`NotConfiguredError` before)."""
        if self.cfg is None:
            raise NotConfiguredError("the monitor is not configured")
        return self.cfg


@dataclass
class ChannelSettings:
    """Periods and options of a configuration (parameters; the periods change at runtime)."""

    use_sim_time: bool = False
    stale_timeout_s: float = 1.0
    publish_period_s: float = 0.1
    diag_period_s: float = 1.0
    hardware_id: str = ""
    block_period_s: float = 0.05
    block_batch_s: float = 0.0


@dataclass
class ChannelStats:
    """Statistics of a channel for its estimator status: written by the worker and the input callbacks, read by the
    publisher. :meth:`reset` starts them afresh in place (the parts keep their reference)."""

    delays_ms: RingStats = field(default_factory=RingStats)
    busy_s: float = 0.0
    data_s: float = 0.0
    cpu_fraction: float = math.nan
    malformed: dict[str, int] = field(default_factory=dict)   # signal -> messages without a usable value
    wrong_types: list[str] = field(default_factory=list)
    errors: int = 0
    last_error: str = ""
    push_started_ns: int = 0           # a pipeline update running since (0: none)
    node_stalls: int = 0               # executor stalls (the node did not look at its inputs)
    node_stall_max_s: float = 0.0
    worker_stalls: int = 0             # worker steps further apart than STALL_NS (GC, compile, ...)
    worker_stall_max_s: float = 0.0

    def reset(self) -> None:
        fresh = ChannelStats()
        for f in fields(self):
            if f.name != "malformed":          # the callbacks and the fan-out keep a reference to it
                setattr(self, f.name, getattr(fresh, f.name))
        self.malformed.clear()


class Outbox:
    """Reports from the worker to the publisher: every report's (K, 6) estimate for ~/modes in order (a cheap message:
    none is coalesced unless the publisher falls ``MODES_QUEUE`` behind), the newest report for /diagnostics."""

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self.latest_report: Report | None = None
        self.modes_queue: deque[tuple[float, np.ndarray]] = deque(maxlen=MODES_QUEUE)
        self.reports_made = 0
        self.reports_published = 0
        self.snapshot: tuple[Report | None, np.ndarray | None] = (None, None)   # what the publisher can always use
        # before the first report of a restored state: its baseline and flags (core.report_assembly.fault_fields)
        self.restored: dict[str, Any] | None = None
