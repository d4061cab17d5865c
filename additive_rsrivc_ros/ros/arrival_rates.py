"""Arrival-rate check of an input stage: each topic's message rate against ``loop_rate_hz`` (ROS-free).

Per topic, (last arrival ns, cumulative message count) points over two rate windows; the rate is the least-squares
slope over the last ``rate_window_s``, judged only when the window holds no pause of the topic, no stall of the node
and no burst. Two judged windows off by more than ``rate_tolerance`` open a mismatch episode (one event), two within
it close it.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable

import numpy as np

from .sync_state import NodeStalls, SyncCounters, SyncEvents


class ArrivalRates:
    """Arrival rates of the topics of one input stage; see the module docstring.

    ``gap_ns(arrivals)`` is the longest arrival spacing that is not a pause (the input kind's: one message per sample
    or per block)."""

    def __init__(self, rate_hz: float, labels: tuple[str, ...], *, window_s: float, tolerance: float,
                 counters: SyncCounters, events: SyncEvents, stalls: NodeStalls,
                 gap_ns: Callable[[np.ndarray], int]) -> None:
        self.rate = float(rate_hz)
        self.labels = labels
        self.window_ns = int(window_s * 1e9)
        self.tolerance = float(tolerance)
        self.counters = counters
        self.events = events
        self.stalls = stalls
        self.gap_ns = gap_ns
        n = len(labels)
        self.pts: list[deque[tuple[int, int]]] = [deque() for _ in range(n)]   # (last arrival ns, cumulative count)
        self.bad = [0] * n
        self.good = [0] * n
        self.mismatch: dict[str, float] = {}    # label -> measured arrival rate (Hz) while mismatched
        self.measured: list[float] = [float("nan")] * n
        self.expected = self.rate

    def record(self, i: int, arrival_ns: int, count: int, now_ns: int) -> None:
        """Topic ``i`` had received ``count`` messages by ``arrival_ns``; points older than two windows go."""
        pts = self.pts[i]
        pts.append((arrival_ns, count))
        while pts and pts[0][0] < now_ns - 2 * self.window_ns:
            pts.popleft()

    def check(self, now_ns: int, time_scale: float = 1.0) -> list[str]:
        """Arrival rate of each topic over the last window vs ``rate_hz * time_scale`` (the speed of the sample
        clock, 1 without sim time); returns the newly mismatched topics' one-line reasons."""
        new = []
        expected = self.rate * time_scale
        self.expected = expected
        for i, pts in enumerate(self.pts):
            rate = self._window_rate(pts, now_ns)
            self.measured[i] = rate
            if rate != rate or not expected > 0.0:       # not judged (nan): pause, stall or too few data
                continue
            label = self.labels[i]
            if abs(rate / expected - 1.0) > self.tolerance:
                self.good[i] = 0
                self.bad[i] += 1
                if self.bad[i] >= 2 and label not in self.mismatch:
                    self.counters.rate_mismatches += 1
                    msg = self.reason(label, rate, expected)
                    self.events.add(now_ns, msg)
                    new.append(msg)
                if label in self.mismatch:
                    self.mismatch[label] = rate
                elif self.bad[i] >= 2:
                    self.mismatch[label] = rate
            else:
                self.bad[i] = 0
                self.good[i] += 1
                if self.good[i] >= 2 and self.mismatch.pop(label, None) is not None:
                    self.events.add(now_ns, f"arrival rate on {label} matches loop_rate_hz again ({rate:.0f} Hz)")
        return new

    def reason(self, label: str, rate: float, expected: float | None = None) -> str:
        """One line: ``arrival rate 2048 Hz on /plant_output, loop_rate_hz 4096``."""
        exp = self.rate if expected is None else expected
        scale = "" if abs(exp - self.rate) < 1e-9 * self.rate else f" x clock speed {exp / self.rate:.3g}"
        return f"arrival rate {rate:.0f} Hz on {label}, loop_rate_hz {self.rate:g}{scale}"

    def _window_rate(self, pts: deque[tuple[int, int]], now_ns: int) -> float:
        """Least-squares slope of the message count over arrival time in the window; nan when not judgeable."""
        lo = now_ns - self.window_ns
        sel = [p for p in list(pts) if p[0] >= lo]
        if len(sel) < 8:
            return float("nan")
        a = np.array([p[0] for p in sel], dtype=np.int64)
        c = np.array([p[1] for p in sel], dtype=float)
        span = int(a[-1] - a[0])
        gap_ns = self.gap_ns(a)
        if span < 0.75 * self.window_ns or now_ns - int(a[-1]) > gap_ns:
            return float("nan")
        if int(np.max(np.diff(a))) > gap_ns or self.stalls.between(int(a[0]), now_ns) > 0:
            return float("nan")                       # a pause of the topic or a stall of the node
        x = (a - a[0]) * 1e-9
        x -= x.mean()
        slope = float(np.dot(x, c - c.mean()) / np.dot(x, x))
        if not slope > 0.0:
            return float("nan")
        # bursts (a lagging publisher catching up, an executor serving topic by topic) are not a rate: judge
        # only windows whose arrivals stay within half a gap of a straight line
        resid_s = np.max(np.abs(c - c.mean() - slope * x)) / slope
        if resid_s > 0.5 * gap_ns * 1e-9:
            return float("nan")
        return slope
