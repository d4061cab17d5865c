"""What the parts of an input stage (:mod:`.sync`, :mod:`.blocks`) share: samples out, counters, events, the node's
stalls and the settings (ROS-free).

Each part receives the objects it reads or writes in its constructor: :class:`SyncCounters` (reported on
/diagnostics), :class:`SyncEvents` (one line per input episode, logged by the worker), :class:`NodeStalls` (the node's
own stalls, never counted as input pauses) and :class:`SyncSettings` (changed at runtime by ``InputSync.update``).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np


@dataclass
class Aligned:
    """Samples ready for the pipeline: times (s), signals (r is None when not configured) and completion
    arrival times (monotonic ns, the arrival of the last of a sample's messages)."""

    t: np.ndarray
    r: np.ndarray | None
    u: np.ndarray
    y: np.ndarray
    arrival_ns: np.ndarray

    def __len__(self) -> int:
        return int(self.t.size)


@dataclass
class SyncCounters:
    """Input-side counters reported on /diagnostics."""

    received: list[int] = field(default_factory=list)   # messages per signal
    aligned: int = 0                                     # samples handed to the pipeline
    dropped: int = 0                                     # messages discarded (unmatched, resync, stale)
    mismatches: int = 0                                  # count-mismatch / misalignment events
    out_of_order: int = 0                                # stamped mode: stamps not increasing on a topic
    unmatched: int = 0                                   # stamped mode: stamps without partners
    gaps: int = 0                                        # order mode: pauses turned into time gaps
    queue_dropped: list[int] = field(default_factory=list)  # per signal: oldest dropped at the queue bound
    rate_mismatches: int = 0                             # arrival-rate mismatch episodes
    node_stall_gaps: int = 0                             # time gaps caused by the node's own stalls

    def to_dict(self) -> dict[str, int | list[int]]:
        return dict(self.__dict__)


class SyncEvents:
    """The input stage's event lines (the last 20), how many there were and when the newest came."""

    def __init__(self) -> None:
        self.lines: deque[str] = deque(maxlen=20)
        self.count = 0
        self.last_ns = 0

    def add(self, now_ns: int, msg: str) -> None:
        self.lines.append(msg)
        self.count += 1
        self.last_ns = now_ns


class NodeStalls:
    """The node's own stalls (start, end) ns, the last 64 (the executor did not run: not an input pause)."""

    def __init__(self) -> None:
        self.spans: deque[tuple[int, int]] = deque(maxlen=64)

    def note(self, start_ns: int, end_ns: int) -> None:
        self.spans.append((int(start_ns), int(end_ns)))

    def between(self, a_ns: int, b_ns: int) -> int:
        """Length (ns) of the node's stalls overlapping ``[a_ns, b_ns]``."""
        return sum(max(0, min(e, b_ns) - max(s, a_ns)) for s, e in list(self.spans))


@dataclass
class SyncSettings:
    """Settings of an input stage in ns / samples (``InputSync.update`` applies a runtime change with its floors)."""

    max_backlog: int = 8            # samples one topic may be ahead of another
    gap_ns: int = 0                 # lateness jump that is a pause
    hold_ns: int = 0                # wait for a catch-up burst before deciding a pause
    quiet_ns: int = 0               # every topic quiet this long: leftovers never match
    silent_req_ns: int = 0          # the requested silence (stale_timeout_s)
    stall_ns: int = 0               # the longest stall of a reliable topic (DDS heartbeat)
    skew_ns: int = 0                # heads arriving further apart after a resync are not partners
    persist_ns: int = 0             # an imbalance is a count mismatch only after this long
    silent_ns: int = 0              # a topic behind the others is lost after this silence
