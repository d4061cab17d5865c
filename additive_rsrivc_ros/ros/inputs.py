"""Inputs of the monitor node: topic names, the input stage, subscriptions and their callbacks, the type check.

The input topics are relative (``reference``, ``plant_input``, ``plant_output``), resolved in the node's namespace and
remappable; every check and message names the resolved topic. Subscriptions are RELIABLE, KEEP_LAST with five seconds of
samples (``qos_depth``), overridable per topic by the standard ``qos_overrides.<topic>.subscription.*`` parameters: over
loopback the only loss left is a reader history overflow while the executor falls behind, which five seconds cover. The
EventsExecutor serves bursts topic by topic (about 3000 messages of one topic before the next), so the alignment
tolerates large temporary count differences. Callbacks only append ``(value, arrival[, stamp])`` to bounded per-topic
deques; the worker aligns them (:mod:`.sync`, :mod:`.blocks`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping
from typing import Any

from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.qos_overriding_options import QoSOverridingOptions
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, Float64MultiArray

from ..config import MonitorConfig, ParamError, SignalConfig
from . import convert as cv
from . import sync as input_sync
from .blocks import BlockSync
from .channel import ChannelContext, ChannelCore, ChannelStats
from .input_stage import InputStage
from .sync import InputSync

JOINT_STATE = "sensor_msgs/msg/JointState"


def signal_names(cfg: MonitorConfig) -> tuple[str, ...]:
    """The configured input signals in the pipeline's order."""
    if cfg.block_input:
        return ("block",)
    return ("reference", "input", "output") if cfg.closed_loop else ("input", "output")


def reader_depth(v: Mapping[str, Any], rate_hz: float) -> int:
    """``qos_depth``, 0 meaning five seconds of samples (at least 100)."""
    return v["qos_depth"] or max(100, int(math.ceil(5.0 * rate_hz)))


def first_line(exc: Exception) -> str:
    """The first line of an exception's text (its type when it has none)."""
    return str(exc).splitlines()[0] if str(exc) else type(exc).__name__


def note_wrong_types(stats: ChannelStats, ctx: ChannelContext, wrong: list[str]) -> None:
    """Record the channel's topics that carry another message type; log them when they change."""
    if wrong and wrong != stats.wrong_types:
        for w in wrong:
            ctx.logger.error(f"wrong message type: {w}")
    stats.wrong_types = wrong


class Inputs:
    """Topic names, input stage, subscriptions and their callbacks (a part of
    :class:`.channel_parts.ChannelParts`)."""

    def __init__(self, ctx: ChannelContext, core: ChannelCore, stats: ChannelStats) -> None:
        self.ctx = ctx
        self.core = core
        self.stats = stats

    def resolve_topics(self, cfg: MonitorConfig, node: Node) -> dict[str, str]:
        """The configured signal topics expanded in the node's namespace and remapped (``-r from:=to``), as
        the subscriptions will use them; every check and message names these (ParamError: invalid name)."""
        out = {}
        for s in self.core.signals:
            try:
                out[s] = node.resolve_topic_name(cfg.signals[s].topic)
            except Exception as exc:  # noqa: BLE001 - rclpy raises RuntimeError / rcl errors for bad names
                raise ParamError(f"parameter '{s}.topic' = {cfg.signals[s].topic!r} is not a valid topic name "
                                 f"({first_line(exc)})") from None
        return out

    def make_sync(self, cfg: MonitorConfig, v: Mapping[str, Any]) -> InputStage:
        """The input stage: :class:`BlockSync` for block input, else :class:`InputSync` (stamped when every signal
        is a JointState)."""
        rate = cfg.loop_rate_hz
        common = {"silent_s": v["stale_timeout_s"], "max_queue": self._queue_samples(cfg, v),
                  "rate_window_s": v["sync.rate_window_s"], "rate_tolerance": v["sync.rate_tolerance"],
                  "gap_s": input_sync.pause_gap_s(v["sync.gap_s"], rate)}
        if cfg.block_input:
            return BlockSync(rate, closed_loop=cfg.closed_loop, label=self.core.topics["block"], convert=cv.block_rows,
                             reorder_s=v["block.reorder_s"], controller=cfg.controller, **common)
        signals = self.core.signals
        return InputSync(signals, rate, stamped=all(cfg.signals[s].type == JOINT_STATE for s in signals),
                         **{**common, **input_sync.settings(v, rate)}, stall_s=v["sync.stall_s"],
                         labels=tuple(self.core.topics[s] for s in signals))

    @staticmethod
    def _queue_samples(cfg: MonitorConfig, v: Mapping[str, Any]) -> int:
        """sync.max_queue_s in samples, never below twice the backlog allowance nor the DDS reader history
        (``qos_depth``): the node holds no fewer samples than DDS already would."""
        rate = cfg.loop_rate_hz
        return max(2 * input_sync.backlog_samples(v["sync.max_backlog_s"], rate),
                   int(math.ceil(v["sync.max_queue_s"] * rate)), reader_depth(v, rate))

    def subscribe(self, node: Node, cfg: MonitorConfig, v: Mapping[str, Any], subs: list[Any]) -> str:
        """Create the signal subscriptions on ``node`` (appended to ``subs``): RELIABLE (``qos_reliable``), KEEP_LAST
        ``qos_depth``, each overridable by the standard ``qos_overrides.<resolved topic>.subscription.{history,depth,
        reliability}`` parameters (rclpy QoSOverridingOptions). Returns a one-line QoS summary; ParamError on a bad
        override."""
        depth = reader_depth(v, cfg.loop_rate_hz)
        opts = QoSOverridingOptions.with_default_policies()
        topics = self.core.topics
        for i, s in enumerate(self.core.signals):
            sc = cfg.signals[s]
            qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                             reliability=ReliabilityPolicy.RELIABLE if v["qos_reliable"]
                             else ReliabilityPolicy.BEST_EFFORT, durability=DurabilityPolicy.VOLATILE)
            joint = sc.type == JOINT_STATE
            block = s == "block"
            cb = self.block_cb() if block else self._joint_cb(i, s, sc) if joint else self._float_cb(i)
            kind = Float64MultiArray if block else JointState if joint else Float64
            try:
                sub = node.create_subscription(kind, topics[s], cb, qos, qos_overriding_options=opts)
            except Exception as exc:  # noqa: BLE001 - rclpy raises several types for a bad override value
                raise ParamError(f"QoS override for {topics[s]} rejected: {first_line(exc)}") from None
            subs.append(sub)
        self._warn_stray_qos_overrides(node._parameter_overrides)
        return ", ".join(f"{topics[s]} {q.reliability.name.lower()} {q.history.name.lower()} {q.depth}"
                         for s, q in zip(self.core.signals, (sub.qos_profile for sub in subs), strict=True))

    def _warn_stray_qos_overrides(self, overrides: Mapping[str, Any]) -> None:
        """A ``qos_overrides.<topic>...`` for none of this node's subscriptions (e.g. the unnamespaced topic
        under a namespace) changes nothing: one warning line naming it and the resolved topics."""
        topics = self.core.topics
        mine = {f"qos_overrides.{t}.subscription." for t in topics.values()}
        stray = sorted(n for n in overrides if n.startswith("qos_overrides.")
                       and ".subscription." in n and not any(n.startswith(m) for m in mine))
        if stray:
            self.ctx.logger.warning(f"QoS override(s) {', '.join(stray)} match no subscription of this node "
                                    f"(its topics: {', '.join(topics.values())})")

    def _float_cb(self, i: int) -> Callable[[Float64], None]:
        sync = self.core.configured_sync()
        q = sync.queues[i]
        over, cap = sync.overflow, sync.max_queue
        mono = time.monotonic_ns
        activity = self.ctx.activity

        def cb(msg: Float64) -> None:
            if activity.active:
                if len(q) >= cap:          # the bounded deque drops its oldest item: count it
                    over[i] += 1
                q.append((msg.data, mono()))
        return cb

    def block_cb(self) -> Callable[[Float64MultiArray], None]:
        sync = self.core.configured_sync()
        if not isinstance(sync, BlockSync):
            raise TypeError("block input needs the block input stage (BlockSync)")
        enqueue, mono = sync.enqueue, time.monotonic_ns
        activity = self.ctx.activity

        def cb(msg: Float64MultiArray) -> None:
            if activity.active:
                enqueue(msg, mono())
        return cb

    def _joint_cb(self, i: int, sig: str, sc: SignalConfig) -> Callable[[JointState], None]:
        sync = self.core.configured_sync()
        q = sync.queues[i]
        over, cap = sync.overflow, sync.max_queue
        mono = time.monotonic_ns
        joint, fld = sc.joint, sc.field
        activity, malformed = self.ctx.activity, self.stats.malformed

        def cb(msg: JointState) -> None:
            if not activity.active:
                return
            try:
                k = msg.name.index(joint) if joint else 0
                value = float(getattr(msg, fld)[k])
            except (ValueError, IndexError):
                malformed[sig] = malformed.get(sig, 0) + 1
                return
            st = msg.header.stamp
            if len(q) >= cap:
                over[i] += 1
            q.append((value, mono(), st.sec * 1_000_000_000 + st.nanosec))
        return cb

    def check_graph(self, found: Mapping[str, list[str]]) -> None:
        """A configured topic carrying another message type (``found``: the graph's topics and types): name the topic
        and both types."""
        wrong = []
        for s in self.core.signals:
            sc = self.core.configured_cfg().signals[s]
            topic = self.core.topics[s]
            others = [t for t in found.get(topic, []) if t != sc.type]
            if others:
                wrong.append(f"topic {topic} ({s}) carries {', '.join(others)} but {s}.type is {sc.type}")
        note_wrong_types(self.stats, self.ctx, wrong)
