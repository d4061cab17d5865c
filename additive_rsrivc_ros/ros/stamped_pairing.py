"""Stamp pairing of ``sensor_msgs/JointState`` topics: the header stamp is the sample time (ROS-free).

Samples match by equal stamps; a stamp that does not increase on its topic is dropped (out of order or repeated), a
stamp without partners on the other topics is dropped (unmatched). After a restored estimator state the times are
offset to lie above its last time only when they do not (a recorder restarted from an earlier time); stamps that
continue after it keep their time, so data that resume where the saved state ended continue the estimate without a
gap, and a real gap is measured as it was.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .sync_state import Aligned, SyncCounters, SyncEvents


class StampedPairing:
    """Pairing of pending samples ``(value, arrival_ns, stamp_ns)`` by stamp; see the module docstring."""

    def __init__(self, signals: tuple[str, ...], *, counters: SyncCounters, events: SyncEvents) -> None:
        self.signals = signals
        self.counters = counters
        self.events = events
        self.time_floor: float | None = None
        self._last_stamp = [-1] * len(signals)
        self._offset_s: float | None = None

    def set_time_floor(self, t_floor: float | None) -> None:
        self.time_floor = t_floor
        self._offset_s = None

    def increasing(self, i: int, items: list[tuple[Any, ...]], now_ns: int) -> list[tuple[Any, ...]]:
        """Drop messages whose stamp does not increase on their topic."""
        keep = []
        last = self._last_stamp[i]
        for item in items:
            if item[2] > last:
                keep.append(item)
                last = item[2]
        self._last_stamp[i] = last
        bad = len(items) - len(keep)
        if bad:
            self.counters.out_of_order += bad
            self.counters.dropped += bad
            self.events.add(now_ns, f"{self.signals[i]}: {bad} out-of-order or repeated stamps dropped")
        return keep

    def take(self, pending: list[list[Any]], now_ns: int) -> Aligned | None:
        """The samples whose stamp every topic has; stamps passed by another topic are dropped (counted)."""
        out_v: list[list[float]] = [[] for _ in self.signals]
        out_s: list[int] = []
        out_a: list[int] = []
        idx = [0] * len(self.signals)
        unmatched = 0
        while all(idx[i] < len(p) for i, p in enumerate(pending)):
            heads = [p[idx[i]] for i, p in enumerate(pending)]
            stamps = [hd[2] for hd in heads]
            top = max(stamps)
            if min(stamps) == top:
                for i, hd in enumerate(heads):
                    out_v[i].append(hd[0])
                    idx[i] += 1
                out_s.append(top)
                out_a.append(max(hd[1] for hd in heads))
                continue
            for i, s in enumerate(stamps):
                if s < top:   # the topic with stamp `top` is past s: s can never be matched
                    idx[i] += 1
                    unmatched += 1
        for i, p in enumerate(pending):
            del p[:idx[i]]
        if unmatched:
            self.counters.unmatched += unmatched
            self.counters.dropped += unmatched
            self.events.add(now_ns, f"{unmatched} messages without partners (stamps missing on another topic) "
                            "dropped")
        return self._aligned(out_v, out_s, out_a) if out_s else None

    def _aligned(self, out_v: list[list[float]], out_s: list[int], out_a: list[int]) -> Aligned:
        stamps_s = np.asarray(out_s, dtype=np.int64)
        if self._offset_s is None:
            self._offset_s = 0.0
            first = stamps_s[0] * 1e-9
            if self.time_floor is not None and first <= self.time_floor:
                self._offset_s = self.time_floor + 1.0 - first   # earlier than the restored data: a 1 s gap
        t = stamps_s * 1e-9 + self._offset_s
        vals = np.asarray(out_v, dtype=float)
        self.counters.aligned += t.size
        sig = self.signals
        r = vals[sig.index("reference")] if "reference" in sig else None
        return Aligned(t, r, vals[sig.index("input")], vals[sig.index("output")], np.asarray(out_a, dtype=np.int64))
