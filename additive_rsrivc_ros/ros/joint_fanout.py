"""One shared ``sensor_msgs/JointState`` topic fanned out to the input stages of the joints that read it.

The subscription's callback only appends ``(msg, arrival_ns)`` to a bounded deque (:meth:`SharedJointTopic.enqueue`);
``msg`` is the serialized message (``raw``: decoded by :mod:`.joint_cdr`, no Python message object) or a message
object. The group's worker converts what arrived in one pass per run of messages with the same layout or name list
(:meth:`SharedJointTopic.fan_out`): the stamps once, each field needed (position, velocity, effort) into an
``(M, joints)`` matrix once, the column of each reading joint looked up once per name list (cached), and each joint's
column appended to that joint's own :class:`..sync.InputSync` queue as the single-joint callback would
(``(value, arrival_ns, stamp_ns)``): pairing by stamp, gaps, rates, silence and queue bounds stay the per-joint
machinery's. A message without a reading joint's name, or whose field array is shorter than its name list, is not a
sample of that joint: counted as malformed on that joint (as ``rsrivc_monitor`` counts it) and announced once per
episode; the joint's other topic then has an unmatched stamp, which its stamped pairing drops and counts.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from rclpy.serialization import deserialize_message

from .joint_cdr import Layout, decode_run, parse_layout

if TYPE_CHECKING:
    from .channel import ChannelStats
    from .input_stage import InputStage


@dataclass
class Reader:
    """One joint's signal read from the topic: the joint's input stage and statistics (``malformed``, ``errors``),
    the index of the signal in its input stage, the signal's name, the joint's name in the messages and the field."""

    sync: InputStage
    stats: ChannelStats
    index: int
    signal: str
    joint: str
    field: str
    delivered: int = 0          # samples appended to the joint's queue


def stamp_ns(msg: Any) -> int:
    """Header stamp in ns."""
    st = msg.header.stamp
    return st.sec * 1_000_000_000 + st.nanosec


def field_matrix(arrays: list[Any], width: int) -> tuple[np.ndarray, np.ndarray | None]:
    """``(M, width)`` float64 matrix of M field arrays, and the mask of the rows of the right length (None: all)."""
    m = len(arrays)
    if all(len(a) == width for a in arrays):
        try:
            flat = np.frombuffer(b"".join(arrays), dtype=np.float64)   # array('d') fields: one copy, no loop
        except TypeError:
            flat = np.asarray([v for a in arrays for v in a], dtype=np.float64)
        if flat.size == m * width:
            return flat.reshape(m, width), None
    out = np.full((m, width), np.nan)
    ok = np.zeros(m, dtype=bool)
    for i, a in enumerate(arrays):
        if len(a) == width:
            out[i] = np.asarray(a, dtype=np.float64)
            ok[i] = True
    return out, ok


class SharedJointTopic:
    """A JointState topic read by several joints; see the module docstring."""

    def __init__(self, topic: str, max_queue: int, *, raw: bool = False, msg_type: Any = None) -> None:
        self.topic = topic
        self.raw = raw                # the subscription hands serialized bytes (decoded here, :mod:`.joint_cdr`)
        self.msg_type = msg_type      # for the messages without a layout (rclpy deserializes them)
        self._layout: Layout | None = None
        self.deserialized = 0
        self.max_queue = int(max_queue)
        self.queue: deque = deque()
        self.readers: list[Reader] = []
        self.received = 0             # messages taken from the queue (worker side)
        self.shed = 0                 # messages dropped at the queue bound (callback side)
        self._shed_seen = 0
        self._columns: dict[tuple[str, ...], list[int]] = {}
        self._open: dict[str, int] = {}   # joint -> messages without it in the current episode

    def add_reader(self, reader: Reader) -> None:
        self.readers.append(reader)
        self._columns.clear()

    @property
    def fields(self) -> tuple[str, ...]:
        return tuple(dict.fromkeys(r.field for r in self.readers))

    def enqueue(self, msg: Any, arrival_ns: int) -> None:
        """Executor thread: queue one message; beyond ``max_queue`` the oldest is dropped (counted)."""
        q = self.queue
        if len(q) >= self.max_queue:
            try:
                q.popleft()
            except IndexError:
                pass
            self.shed += 1
        q.append((msg, arrival_ns))

    def columns(self, names: list[str]) -> list[int]:
        """Column of each reader's joint in a message with ``names`` (-1: absent), cached per name list."""
        key = tuple(names)
        cols = self._columns.get(key)
        if cols is None:
            pos = {n: i for i, n in enumerate(key)}
            cols = [pos.get(r.joint, -1) for r in self.readers]
            if len(self._columns) > 64:
                self._columns.clear()
            self._columns[key] = cols
        return cols

    def fan_out(self, now_ns: int) -> int:
        """Worker thread: convert the queued messages and append each reader's samples; returns the messages done."""
        q = self.queue
        m = len(q)
        shed = self.shed - self._shed_seen
        self._shed_seen += shed
        if shed:
            for r in self.readers:       # a message lost at the bound is a sample lost for every joint that reads it
                r.sync.overflow[r.index] += shed
        if not m:
            return 0
        items = [q.popleft() for _ in range(m)]
        self.received += m
        if self.raw:
            self._fan_out_raw(items, now_ns)
            return m
        start = 0
        while start < m:
            names = items[start][0].name
            end = start + 1
            while end < m and items[end][0].name == names:
                end += 1
            self._feed(items[start:end] if start or end < m else items, names, now_ns)
            start = end
        return m

    def _fan_out_raw(self, items: list[tuple[bytes, int]], now_ns: int) -> None:
        """Serialized messages: runs of one layout decoded in one pass (:mod:`.joint_cdr`); a message without a
        layout is deserialized by rclpy."""
        run: list[tuple[bytes, int]] = []
        for item in items:
            raw = item[0]
            if self._layout is not None and self._layout.matches(raw):
                run.append(item)
                continue
            self._feed_raw(run, now_ns)
            run = []
            self._layout = parse_layout(raw)
            if self._layout is not None:
                run.append(item)
            else:
                self.deserialized += 1
                msg = deserialize_message(raw, self.msg_type)
                self._feed([(msg, item[1])], msg.name, now_ns)
        self._feed_raw(run, now_ns)

    def _feed_raw(self, run: list[tuple[bytes, int]], now_ns: int) -> None:
        layout = self._layout    # the run's (a run is only ever collected under a layout)
        if run and layout is not None:
            stamps, mats = decode_run([r for r, _ in run], layout, self.fields)
            self._feed_run(list(layout.names), stamps, [a for _, a in run], mats, now_ns)

    def _feed(self, run: list[tuple[Any, int]], names: list[str], now_ns: int) -> None:
        """One run of message objects with the same name list -> every reader's queue."""
        width = len(names)
        stamps = [stamp_ns(msg) for msg, _ in run]
        mats = {f: field_matrix([getattr(msg, f) for msg, _ in run], width) for f in self.fields}
        self._feed_run(names, stamps, [a for _, a in run], mats, now_ns)

    def _feed_run(self, names: list[str], stamps: list[int], arrivals: list[int],
                  mats: dict[str, tuple[np.ndarray, np.ndarray | None]], now_ns: int) -> None:
        """Messages with one name list, converted: each reader's column to its joint's queue."""
        n = len(stamps)
        width = len(names)
        missed: dict[str, tuple[InputStage, int, str]] = {}
        for r, col in zip(self.readers, self.columns(names), strict=True):
            if col < 0:
                self._malformed(r, n)
                missed[r.joint] = (r.sync, n, f"joint '{r.joint}' not in {n} message(s) on {self.topic} (names: "
                                   f"{', '.join(names[:8])}{' ...' if width > 8 else ''})")
                continue
            mat, ok = mats[r.field]
            vals = mat[:, col].tolist()
            rows: Iterable[tuple[Any, int, int]]
            if ok is None:
                rows = zip(vals, arrivals, stamps, strict=True)
                k = n
            else:
                keep = np.flatnonzero(ok).tolist()
                rows = ((vals[i], arrivals[i], stamps[i]) for i in keep)
                k = len(keep)
                if k < n:
                    self._malformed(r, n - k)
                    missed.setdefault(r.joint, (r.sync, n - k, f"{n - k} message(s) on {self.topic} with fewer "
                                                f"{r.field} values than names: no sample of joint '{r.joint}'"))
            dq = r.sync.queues[r.index]
            over = len(dq) + k - dq.maxlen if dq.maxlen is not None else 0
            if over > 0:                  # the bounded deque drops its oldest items: count them as its callback does
                r.sync.overflow[r.index] += over
            dq.extend(rows)
            r.delivered += k
        self._episodes(missed, now_ns)

    @staticmethod
    def _malformed(r: Reader, n: int) -> None:
        """``n`` messages gave no sample of ``r``'s signal: malformed on that joint (as ``rsrivc_monitor`` counts)."""
        mal = r.stats.malformed
        mal[r.signal] = mal.get(r.signal, 0) + n

    def _episodes(self, missed: dict[str, tuple[InputStage, int, str]], now_ns: int) -> None:
        """One event per joint when messages without it begin on this topic, one when it is back."""
        for joint, (sync, n, text) in missed.items():
            if not self._open.get(joint):
                sync._event(now_ns, text)
            self._open[joint] = self._open.get(joint, 0) + n
        for r in self.readers:
            count = self._open.get(r.joint, 0)
            if count and r.joint not in missed:
                r.sync._event(now_ns, f"joint '{r.joint}' back in the messages on {self.topic} after {count} "
                              "message(s) without it")
                self._open[r.joint] = 0
