"""Alignment of the r, u, y input streams into samples (ROS-free, used by the monitor node).

* **order** (``std_msgs/Float64``): the k-th message of every topic is sample k, timed on the nominal grid ``t_k =
  t_anchor + (k - k_anchor) / loop_rate_hz``; arrival times only decide whether a real pause happened (a lateness jump
  above ``gap_s`` not caught up within ``hold_s``: the grid is re-anchored and the pipeline sees a gap). A count
  mismatch between topics resynchronizes them (pending samples discarded, heads re-aligned by arrival time).
* **stamped** (``sensor_msgs/JointState``): the header stamp is the sample time; samples match by equal stamps,
  unmatched, out-of-order or repeated stamps are dropped.

Callbacks only append to :attr:`InputSync.queues`; :meth:`InputSync.collect` runs in the worker. Queues are bounded by
``max_queue`` samples per topic (the oldest dropped and counted); each topic's arrival rate is checked against
``loop_rate_hz`` (:meth:`InputSync.check_rates`); the node's own stalls are counted apart, never as input pauses.
"""

from __future__ import annotations

import bisect
import math
import threading
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

# bytes one queued sample costs at most: a 2- or 3-tuple (56-64 B), a float (24 B), one or two ints (<= 36 B
# each), a deque/list slot (8 B); measured with tracemalloc in test/test_node_sync.py
BYTES_PER_SAMPLE = 200


def backlog_samples(max_backlog_s: float, rate_hz: float) -> int:
    """``sync.max_backlog_s`` in samples (at least 8)."""
    return max(8, int(math.ceil(max_backlog_s * rate_hz)))


def pause_gap_s(gap_s: float, rate_hz: float) -> float:
    """``sync.gap_s``, with 0 meaning automatic: ten sample periods, at least 0.1 s."""
    return gap_s if gap_s > 0.0 else max(0.1, 10.0 / rate_hz)


def settings(values: Mapping[str, Any], rate_hz: float) -> dict[str, Any]:
    """:meth:`InputSync.update` arguments from the parameters in ``values`` (at start-up all of them, on a runtime
    change the changed ones): ``stale_timeout_s`` and ``sync.{max_backlog,gap,quiet,hold}_s``."""
    convert: dict[str, tuple[str, Callable[[Any], float]]] = {"stale_timeout_s": ("silent_s", float),
               "sync.max_backlog_s": ("max_backlog", lambda s: backlog_samples(float(s), rate_hz)),
               "sync.gap_s": ("gap_s", lambda s: pause_gap_s(float(s), rate_hz)),
               "sync.quiet_s": ("quiet_s", float), "sync.hold_s": ("hold_s", float)}
    return {arg: f(values[name]) for name, (arg, f) in convert.items() if name in values}


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


class InputSync:
    """Turns per-topic message queues into aligned samples; see the module docstring.

    ``signals`` are the names in the order the pipeline wants them, e.g. ``("reference", "input", "output")``
    or ``("input", "output")`` in open loop.
    """

    wake: threading.Event | None = None   # block input sets it per message; None: the worker polls every period

    def __init__(self, signals: tuple[str, ...], rate_hz: float, *, stamped: bool, max_backlog: int,
                 quiet_s: float, gap_s: float, hold_s: float, skew_s: float | None = None,
                 silent_s: float | None = None, stall_s: float = 4.0, max_queue: int = 1 << 20,
                 labels: tuple[str, ...] | None = None, rate_window_s: float = 2.0,
                 rate_tolerance: float = 0.02) -> None:
        if not signals or not all(s in ("reference", "input", "output") for s in signals):
            raise ValueError(f"signals must be a non-empty subset of reference/input/output, got {signals}")
        if not (rate_hz > 0.0):
            raise ValueError(f"rate_hz must be > 0, got {rate_hz}")
        if max_backlog < 1 or quiet_s <= 0.0 or gap_s <= 0.0 or hold_s < 0.0 or not stall_s >= 0.0:
            raise ValueError("max_backlog >= 1, quiet_s > 0, gap_s > 0, hold_s >= 0 and stall_s >= 0 are required")
        if max_queue < 2 * max_backlog or not rate_window_s > 0.0 or not rate_tolerance > 0.0:
            raise ValueError("max_queue >= 2 max_backlog, rate_window_s > 0 and rate_tolerance > 0 are required")
        self.signals = tuple(signals)
        self.n = len(signals)
        self.rate = float(rate_hz)
        self.h_ns = 1e9 / self.rate
        self.stamped = stamped
        self._stall_ns = int(stall_s * 1e9)
        InputSync.update(self, max_backlog=max_backlog, quiet_s=quiet_s, gap_s=gap_s, hold_s=hold_s,
                         silent_s=quiet_s if silent_s is None else silent_s)
        self.skew_ns = int((0.5 / self.rate if skew_s is None else skew_s) * 1e9)
        self.labels = tuple(labels) if labels is not None else self.signals
        self.max_queue = int(max_queue)
        # callbacks append here; a full deque drops its oldest item, the callback counts it in `overflow`
        self.queues: list[deque] = [deque(maxlen=self.max_queue) for _ in signals]
        self.overflow = [0] * self.n
        self._overflow_seen = [0] * self.n
        self._overflowing = [0] * self.n          # messages dropped in the current episode (0: none open)
        self.pending: list[list[tuple]] = [[] for _ in signals]
        self.last_arrival_ns = [0] * self.n
        self.counters = SyncCounters(received=[0] * self.n, queue_dropped=[0] * self.n)
        self.rate_window_ns = int(rate_window_s * 1e9)
        self.rate_tolerance = float(rate_tolerance)
        self._rate_pts: list[deque] = [deque() for _ in signals]   # (last arrival ns, cumulative count)
        self._rate_bad = [0] * self.n
        self._rate_good = [0] * self.n
        self.rate_mismatch: dict[str, float] = {}    # label -> measured arrival rate (Hz) while mismatched
        self.measured_rate: list[float] = [float("nan")] * self.n
        self.stalls: deque[tuple[int, int]] = deque(maxlen=64)
        self.expected_rate = self.rate   # the node's own stalls (start, end) ns
        self.events: deque[str] = deque(maxlen=20)
        self.n_events = 0
        self.last_event_ns = 0
        self.time_floor: float | None = None
        self._last_stamp = [-1] * self.n
        self._offset_s: float | None = None
        self._restart_grid()
        self._last_t: float | None = None
        self._last_arr = 0
        self._align_heads = False
        self._imbalance_since: int | None = None
        self._last_lag = 0

    # ----------------------------------------------------------------------------------------- control
    def update(self, *, silent_s: float | None = None, max_backlog: int | None = None, gap_s: float | None = None,
               quiet_s: float | None = None, hold_s: float | None = None) -> None:
        """Apply (validated) settings, at start-up and on a runtime parameter change alike: the same conversions and
        floors (``silent_s`` and the count-mismatch persistence never below a stall). None leaves a setting as is."""
        if max_backlog is not None:
            self.max_backlog = int(max_backlog)
        if gap_s is not None:
            self.gap_ns = int(gap_s * 1e9)
        if hold_s is not None:
            self.hold_ns = int(hold_s * 1e9)
        if quiet_s is not None:
            self.quiet_ns = int(quiet_s * 1e9)
        if silent_s is not None:
            self._silent_req_ns = int(silent_s * 1e9)
        # a topic may stall while the others continue: reliable DDS recovers a lost datagram only at the writer's
        # next heartbeat (Fast DDS: every 3 s); an imbalance is a count mismatch only after it outlasts that
        self.persist_ns = max(self._stall_ns, 2 * self.quiet_ns)
        # a topic behind the others is lost only after a silence longer than a stall too
        self.silent_ns = max(self._silent_req_ns, self.persist_ns)

    @property
    def pairing(self) -> str:
        """How samples are paired (the node's start-up line)."""
        return "stamped" if self.stamped else "arrival order"

    def _restart_grid(self) -> None:
        self._anchor_k = 0
        self._anchor_t: float | None = None
        self._anchor_arr = 0
        self._k = 0

    def _event(self, now_ns: int, msg: str) -> None:
        self.events.append(msg)
        self.n_events += 1
        self.last_event_ns = now_ns

    def set_time_floor(self, t_floor: float | None) -> None:
        """Emit times above ``t_floor + 1 s`` from now on (after restoring a saved estimator state)."""
        self.time_floor = t_floor
        self._offset_s = None
        self._restart_grid()

    def resync(self, now_ns: int, reason: str, *, count: bool = True) -> None:
        """Discard everything pending; re-align the heads and restart the time grid after a gap."""
        n_drop = sum(len(p) for p in self.pending)
        self.pending = [[] for _ in self.signals]
        self.counters.dropped += n_drop
        if count:
            self.counters.mismatches += 1
        self._event(now_ns, f"{reason}; {n_drop} pending messages discarded, streams resynchronized")
        self._restart_grid()
        self._align_heads = not self.stamped

    def _drain(self, now_ns: int) -> None:
        for i, q in enumerate(self.queues):
            m = len(q)
            lost = self.overflow[i] - self._overflow_seen[i]
            self._overflow_seen[i] += lost
            if m:
                items = [q.popleft() for _ in range(m)]
                self.counters.received[i] += m + lost
                self.last_arrival_ns[i] = items[-1][1]
                pts = self._rate_pts[i]
                pts.append((items[-1][1], self.counters.received[i]))
                while pts and pts[0][0] < now_ns - 2 * self.rate_window_ns:
                    pts.popleft()
                if self.stamped:
                    items = self._increasing(i, items, now_ns)
                self.pending[i].extend(items)
            excess = len(self.pending[i]) - self.max_queue
            if excess > 0:
                del self.pending[i][:excess]
            self._queue_drops(i, lost + max(excess, 0), now_ns)

    def _queue_drops(self, i: int, n_drop: int, now_ns: int) -> None:
        """Count oldest-dropped samples of topic ``i``; one event when an episode starts and one when it ends."""
        if n_drop > 0:
            self.counters.queue_dropped[i] += n_drop
            self.counters.dropped += n_drop
            if not self._overflowing[i]:
                self._event(now_ns, f"queue of {self.labels[i]} full ({self.max_queue} samples, "
                            f"{self.max_queue / self.rate:.3g} s): dropping the oldest messages")
            self._overflowing[i] += n_drop
            if not self.stamped:
                self._restart_grid()
                self._align_heads = True
        elif self._overflowing[i] and len(self.pending[i]) + len(self.queues[i]) < self.max_queue // 2:
            self._event(now_ns, f"queue of {self.labels[i]} below its bound again; {self._overflowing[i]} "
                        "oldest messages were dropped")
            self._overflowing[i] = 0

    def queue_bytes(self) -> int:
        """Upper bound of the memory the queued samples take (both bounded stages of every topic)."""
        return 2 * self.n * self.max_queue * BYTES_PER_SAMPLE

    def queue_reasons(self) -> list[str]:
        """Topics whose queue is full in an open episode: one WARN reason each."""
        return [f"queue of {lb} full: dropping the oldest messages ({n} so far)"
                for lb, n, ov in zip(self.labels, self.counters.queue_dropped, self._overflowing, strict=True) if ov]

    def _increasing(self, i: int, items: list[tuple], now_ns: int) -> list[tuple]:
        """Stamped mode: drop messages whose stamp does not increase on their topic."""
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
            self._event(now_ns, f"{self.signals[i]}: {bad} out-of-order or repeated stamps dropped")
        return keep

    def latest_arrival(self, i: int) -> int:
        """Arrival (ns) of topic ``i``'s newest message, including messages the worker has not drained yet."""
        try:
            return max(self.last_arrival_ns[i], self.queues[i][-1][1])
        except IndexError:
            return self.last_arrival_ns[i]

    def silent(self, now_ns: int, timeout_s: float, looking_since_ns: int = 0) -> list[str]:
        """Signals without a message for ``timeout_s`` (never received counts as silent) although the node
        was looking: only when the executor has been running for longer than ``timeout_s``
        (``looking_since_ns``: start of its current uninterrupted run); otherwise nothing can be told."""
        lim = int(timeout_s * 1e9)
        if looking_since_ns and now_ns - looking_since_ns <= lim:
            return []
        out = []
        for i, s in enumerate(self.signals):
            a = self.latest_arrival(i)
            if a == 0 or now_ns - a > lim:
                out.append(s)
        return out

    def note_stall(self, start_ns: int, end_ns: int) -> None:
        """The node's own stall (the executor did not run from ``start_ns`` to ``end_ns``)."""
        self.stalls.append((int(start_ns), int(end_ns)))

    def _stalled_between(self, a_ns: int, b_ns: int) -> int:
        """Length (ns) of the node's stalls overlapping ``[a_ns, b_ns]``."""
        return sum(max(0, min(e, b_ns) - max(s, a_ns)) for s, e in list(self.stalls))

    def check_rates(self, now_ns: int, time_scale: float = 1.0) -> list[str]:
        """Arrival rate of each topic over the last ``rate_window_s`` vs ``rate_hz * time_scale`` (the speed of
        the sample clock, 1 without sim time); returns the newly mismatched topics' one-line reasons."""
        new = []
        expected = self.rate * time_scale
        self.expected_rate = expected
        for i, pts in enumerate(self._rate_pts):
            rate = self._window_rate(i, pts, now_ns)
            self.measured_rate[i] = rate
            if rate != rate or not expected > 0.0:       # not judged (nan): pause, stall or too few data
                continue
            label = self.labels[i]
            if abs(rate / expected - 1.0) > self.rate_tolerance:
                self._rate_good[i] = 0
                self._rate_bad[i] += 1
                if self._rate_bad[i] >= 2 and label not in self.rate_mismatch:
                    self.counters.rate_mismatches += 1
                    msg = self.rate_reason(label, rate, expected)
                    self._event(now_ns, msg)
                    new.append(msg)
                if label in self.rate_mismatch:
                    self.rate_mismatch[label] = rate
                elif self._rate_bad[i] >= 2:
                    self.rate_mismatch[label] = rate
            else:
                self._rate_bad[i] = 0
                self._rate_good[i] += 1
                if self._rate_good[i] >= 2 and self.rate_mismatch.pop(label, None) is not None:
                    self._event(now_ns, f"arrival rate on {label} matches loop_rate_hz again ({rate:.0f} Hz)")
        return new

    def _arrival_gap_ns(self, arrivals_ns: np.ndarray) -> int:
        """Longest arrival spacing that is not a pause of the topic (one message per sample: the data gap)."""
        return self.gap_ns

    @property
    def arrival_is_the_clock(self) -> bool:
        """The samples' times come from their arrival (Float64 topics): an arrival rate that contradicts
        ``loop_rate_hz`` is then a wrong time scale. Header-stamped samples carry their own time."""
        return not self.stamped

    @property
    def rate_error(self) -> str:
        """One line when the arrival rate of an input whose arrival is its clock contradicts ``loop_rate_hz`` (the
        model's time scale would be wrong: nothing is published then), else ``''``."""
        if not self.rate_mismatch or not self.arrival_is_the_clock:
            return ""
        label, rate = next(iter(self.rate_mismatch.items()))
        return (f"loop_rate_hz disagrees with the data's timing ({self.rate_reason(label, rate, self.expected_rate)}):"
                " no estimate is published until they agree")

    def lasting_reasons(self) -> list[str]:
        """Lasting problems specific to the input kind (none for topics; block input: the controller invariant)."""
        return []

    def extra_values(self) -> dict[str, Any]:
        """Estimator-status values specific to the input kind (none for topics; block input: its counters)."""
        return {}

    def rate_reason(self, label: str, rate: float, expected: float | None = None) -> str:
        """One line: ``arrival rate 2048 Hz on /plant_output, loop_rate_hz 4096``."""
        exp = self.rate if expected is None else expected
        scale = "" if abs(exp - self.rate) < 1e-9 * self.rate else f" x clock speed {exp / self.rate:.3g}"
        return f"arrival rate {rate:.0f} Hz on {label}, loop_rate_hz {self.rate:g}{scale}"

    def _window_rate(self, i: int, pts: deque, now_ns: int) -> float:
        """Least-squares slope of the message count over arrival time in the window; nan when not judgeable."""
        lo = now_ns - self.rate_window_ns
        sel = [p for p in list(pts) if p[0] >= lo]
        if len(sel) < 8:
            return float("nan")
        a = np.array([p[0] for p in sel], dtype=np.int64)
        c = np.array([p[1] for p in sel], dtype=float)
        span = int(a[-1] - a[0])
        gap_ns = self._arrival_gap_ns(a)
        if span < 0.75 * self.rate_window_ns or now_ns - int(a[-1]) > gap_ns:
            return float("nan")
        if int(np.max(np.diff(a))) > gap_ns or self._stalled_between(int(a[0]), now_ns) > 0:
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

    # ----------------------------------------------------------------------------------------- alignment
    def collect(self, now_ns: int, *, idle_since_ns: int = 0, ros_now_s: float = 0.0) -> Aligned | None:
        """Align what has arrived; ``idle_since_ns``: last time the executor had nothing to do (pause check)."""
        self._drain(now_ns)
        if self.stamped:
            return self._collect_stamped(now_ns)
        return self._collect_order(now_ns, idle_since_ns, ros_now_s)

    def _bound_backlog(self, now_ns: int, lens: list[int]) -> bool:
        """One topic ahead of another by more than ``max_backlog``: drop (silent partner) or resync."""
        if max(lens) - min(lens) <= self.max_backlog:
            self._imbalance_since = None
            return False
        behind = [s for s, n_ in zip(self.signals, lens, strict=True) if n_ == min(lens)]
        silent = [s for s, i in ((s, self.signals.index(s)) for s in behind)
                  if self.last_arrival_ns[i] == 0 or now_ns - self.last_arrival_ns[i] > self.silent_ns]
        if not silent:
            # executors deliver bursts topic by topic: only a lasting imbalance is a count mismatch
            if self._imbalance_since is None:
                self._imbalance_since = now_ns
            if now_ns - self._imbalance_since < self.persist_ns:
                return False
        self._imbalance_since = None
        if silent:
            n_drop = sum(len(p) for p in self.pending)
            self.pending = [[] for _ in self.signals]
            self.counters.dropped += n_drop
            self._event(now_ns, f"no data on {', '.join(silent)} while the other topics continue; "
                        f"{n_drop} unmatched messages discarded")
            self._restart_grid()
            self._align_heads = not self.stamped
        else:
            self.resync(now_ns, "count mismatch: " + ", ".join(f"{s} {n_}" for s, n_ in zip(self.signals, lens,
                                                                                           strict=True))
                        + " pending messages")
        return True

    def _collect_order(self, now_ns: int, idle_since_ns: int, ros_now_s: float) -> Aligned | None:
        if self._align_heads:
            if not all(self.pending):
                return None
            # after a resync: drop heads that arrived well before the newest head (their partners are gone)
            while all(self.pending):
                heads = [p[0][1] for p in self.pending]
                newest = max(heads)
                stale = [i for i, a in enumerate(heads) if a < newest - self.skew_ns]
                if not stale:
                    break
                for i in stale:   # arrivals increase along a topic: cut all heads older than newest - skew at once
                    k = bisect.bisect_left(self.pending[i], newest - self.skew_ns, key=lambda it: it[1])
                    del self.pending[i][:max(k, 1)]
                    self.counters.dropped += max(k, 1)
            if not all(self.pending):
                return None
            self._align_heads = False
        lens = [len(p) for p in self.pending]
        if self._bound_backlog(now_ns, lens):
            return None
        n = min(lens)
        if n == 0 or min(lens) != max(lens):
            # pause check: every topic quiet and the executor idle since -> the leftovers can never match
            last = max(self.last_arrival_ns)
            if (max(lens) > n and now_ns - last > self.quiet_ns and idle_since_ns > last):
                taken = self._take_order(n, now_ns, ros_now_s) if n else None
                self.resync(now_ns, "count mismatch after all topics went quiet: "
                            + ", ".join(f"{s} +{n_ - n}" for s, n_ in zip(self.signals, lens, strict=True)))
                return taken
            if n == 0:
                return None
        return self._take_order(n, now_ns, ros_now_s)

    def _take_order(self, n: int, now_ns: int, ros_now_s: float) -> Aligned | None:
        vals = np.empty((self.n, n))
        arr = np.zeros(n, dtype=np.int64)
        for i, p in enumerate(self.pending):
            block = p[:n]
            del p[:n]
            vals[i] = [b[0] for b in block]
            np.maximum(arr, np.fromiter((b[1] for b in block), dtype=np.int64, count=n), out=arr)
        # time grid. A pause is a jump of the lateness between consecutive samples by more than gap_s that
        # is not taken back by a catch-up burst (a stalled publisher or executor delivers the held samples
        # quickly, bringing the lateness back); wait hold_s for such a burst before deciding.
        h = 1.0 / self.rate
        t = np.empty(n)
        j = 0
        while j < n:
            if self._anchor_t is None:
                t0 = ros_now_s
                if self._last_t is not None:
                    t0 = max(t0, self._last_t + max(2.0 * h, (arr[j] - self._last_arr) * 1e-9))
                if self.time_floor is not None:
                    t0 = max(t0, self.time_floor + 1.0)
                self._anchor_t, self._anchor_k, self._anchor_arr = t0, self._k, int(arr[j])
                self._last_lag = 0
            kk = self._k + np.arange(n - j) - self._anchor_k
            lag = arr[j:] - (self._anchor_arr + np.round(kk * self.h_ns).astype(np.int64))
            base = np.concatenate(([self._last_lag], lag[:-1]))
            stop = n - j
            pause = False
            for jl in np.flatnonzero(lag - base > self.gap_ns):
                if lag[-1] - base[jl] <= self.gap_ns // 2:
                    continue                      # taken back by a burst: a stall, not a pause
                if now_ns - int(arr[j + jl]) < self.hold_ns:   # decide hold_s after the late sample arrived
                    self._give_back(vals[:, j + jl:], arr[j + jl:])
                    n = j + int(jl)
                else:
                    pause = True
                    jump = (lag[jl] - base[jl]) * 1e-9
                    a_prev = int(arr[j + jl - 1]) if j + jl > 0 else self._last_arr
                    if self._stalled_between(a_prev, int(arr[j + jl])) > 0.5 * (lag[jl] - base[jl]):
                        self.counters.node_stall_gaps += 1
                        self._event(now_ns, f"the node stalled ({jump:.3g} s late samples not taken back): time "
                                    "gap, estimator re-primed (not an input pause)")
                    else:
                        self.counters.gaps += 1
                        self._event(now_ns, f"input pause of {jump:.3g} s: time gap, estimator re-primed")
                stop = int(jl)
                break
            t[j:j + stop] = self._anchor_t + kk[:stop] * h
            if stop:
                self._last_lag = int(lag[stop - 1])
            self._k += stop
            j += stop
            if pause:
                if j:
                    self._last_t, self._last_arr = float(t[j - 1]), int(arr[j - 1])
                self._anchor_t = None            # the next sample starts a new grid after a time gap
        if n == 0:
            return None
        self._last_t, self._last_arr = float(t[n - 1]), int(arr[n - 1])
        self.counters.aligned += n
        r = vals[self.signals.index("reference"), :n] if "reference" in self.signals else None
        return Aligned(t[:n].copy(), None if r is None else r.copy(), vals[self.signals.index("input"), :n].copy(),
                       vals[self.signals.index("output"), :n].copy(), arr[:n].copy())

    def _give_back(self, vals: np.ndarray, arr: np.ndarray) -> None:
        """Return aligned-but-held samples to the front of the pending lists (arrival = completion time)."""
        for i in range(self.n):
            self.pending[i][:0] = [(float(v), int(a)) for v, a in zip(vals[i], arr, strict=True)]

    def _collect_stamped(self, now_ns: int) -> Aligned | None:
        out_v: list[list[float]] = [[] for _ in self.signals]
        out_s: list[int] = []
        out_a: list[int] = []
        idx = [0] * self.n
        unmatched = 0
        while all(idx[i] < len(p) for i, p in enumerate(self.pending)):
            heads = [p[idx[i]] for i, p in enumerate(self.pending)]
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
        for i, p in enumerate(self.pending):
            del p[:idx[i]]
        if unmatched:
            self.counters.unmatched += unmatched
            self.counters.dropped += unmatched
            self._event(now_ns, f"{unmatched} messages without partners (stamps missing on another topic) dropped")
        self._bound_backlog(now_ns, [len(p) for p in self.pending])
        if not out_s:
            return None
        stamps_s = np.asarray(out_s, dtype=np.int64)
        if self._offset_s is None:
            self._offset_s = 0.0
            first = stamps_s[0] * 1e-9
            if self.time_floor is not None and first <= self.time_floor + 1.0:
                self._offset_s = self.time_floor + 1.0 - first
        t = stamps_s * 1e-9 + self._offset_s
        vals = np.asarray(out_v, dtype=float)
        self.counters.aligned += t.size
        r = vals[self.signals.index("reference")] if "reference" in self.signals else None
        return Aligned(t, r, vals[self.signals.index("input")], vals[self.signals.index("output")],
                       np.asarray(out_a, dtype=np.int64))
