"""Arrival-order pairing of ``std_msgs/Float64`` topics: the k-th message of every topic is sample k (ROS-free).

Samples are timed on the nominal grid ``t_k = t_anchor + (k - k_anchor) / loop_rate_hz``; arrival times only decide
whether a real pause happened: a lateness jump above ``gap_s`` not caught up within ``hold_s`` re-anchors the grid and
the pipeline sees a gap (a jump during the node's own stall is counted apart). After a resync the heads of the topics
are re-aligned by arrival time (heads older than the newest by more than the skew have lost their partners).
"""

from __future__ import annotations

import bisect

import numpy as np

from .input_queues import InputQueues
from .sync_state import Aligned, NodeStalls, SyncCounters, SyncEvents, SyncSettings


class OrderPairing:
    """The time grid and the pairing of pending samples by arrival order; see the module docstring."""

    def __init__(self, signals: tuple[str, ...], rate_hz: float, *, settings: SyncSettings, queues: InputQueues,
                 counters: SyncCounters, events: SyncEvents, stalls: NodeStalls) -> None:
        self.signals = signals
        self.rate = float(rate_hz)
        self.h_ns = 1e9 / self.rate
        self.settings = settings
        self.queues = queues
        self.counters = counters
        self.events = events
        self.stalls = stalls
        self.time_floor: float | None = None
        self.align_heads = False          # after a resync: the heads are re-aligned before pairing
        self._last_t: float | None = None
        self._last_arr = 0
        self._last_lag = 0
        self.restart_grid()

    def restart_grid(self) -> None:
        self._anchor_k = 0
        self._anchor_t: float | None = None
        self._anchor_arr = 0
        self._k = 0

    def heads_aligned(self) -> bool:
        """After a resync: drop heads that arrived well before the newest head (their partners are gone); False
        while a topic has nothing pending."""
        if not self.align_heads:
            return True
        pending = self.queues.pending
        if not all(pending):
            return False
        skew = self.settings.skew_ns
        while all(pending):
            heads = [p[0][1] for p in pending]
            newest = max(heads)
            stale = [i for i, a in enumerate(heads) if a < newest - skew]
            if not stale:
                break
            for i in stale:   # arrivals increase along a topic: cut all heads older than newest - skew at once
                k = bisect.bisect_left(pending[i], newest - skew, key=lambda it: it[1])
                del pending[i][:max(k, 1)]
                self.counters.dropped += max(k, 1)
        if not all(pending):
            return False
        self.align_heads = False
        return True

    def take(self, n: int, now_ns: int, ros_now_s: float) -> Aligned | None:
        """The first ``n`` pending samples of every topic on the time grid (samples after an undecided late one are
        given back to wait ``hold_s``)."""
        vals = np.empty((len(self.signals), n))
        arr = np.zeros(n, dtype=np.int64)
        for i, p in enumerate(self.queues.pending):
            block = p[:n]
            del p[:n]
            vals[i] = [b[0] for b in block]
            np.maximum(arr, np.fromiter((b[1] for b in block), dtype=np.int64, count=n), out=arr)
        t = np.empty(n)
        n = self._time(vals, arr, t, n, now_ns, ros_now_s)
        if n == 0:
            return None
        self._last_t, self._last_arr = float(t[n - 1]), int(arr[n - 1])
        self.counters.aligned += n
        sig = self.signals
        r = vals[sig.index("reference"), :n] if "reference" in sig else None
        return Aligned(t[:n].copy(), None if r is None else r.copy(), vals[sig.index("input"), :n].copy(),
                       vals[sig.index("output"), :n].copy(), arr[:n].copy())

    def _time(self, vals: np.ndarray, arr: np.ndarray, t: np.ndarray, n: int, now_ns: int, ros_now_s: float) -> int:
        """Fill ``t`` on the grid; returns how many samples are released. A pause is a jump of the lateness between
        consecutive samples by more than gap_s that is not taken back by a catch-up burst (a stalled publisher or
        executor delivers the held samples quickly, bringing the lateness back); wait hold_s for such a burst."""
        h = 1.0 / self.rate
        gap_ns, hold_ns = self.settings.gap_ns, self.settings.hold_ns
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
            for jl in np.flatnonzero(lag - base > gap_ns):
                if lag[-1] - base[jl] <= gap_ns // 2:
                    continue                      # taken back by a burst: a stall, not a pause
                if now_ns - int(arr[j + jl]) < hold_ns:   # decide hold_s after the late sample arrived
                    self._give_back(vals[:, j + jl:], arr[j + jl:])
                    n = j + int(jl)
                else:
                    pause = True
                    self._pause(int(lag[jl] - base[jl]), int(arr[j + jl - 1]) if j + jl > 0 else self._last_arr,
                                int(arr[j + jl]), now_ns)
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
        return n

    def _pause(self, jump_ns: int, a_prev: int, a_late: int, now_ns: int) -> None:
        """A time gap: the node's own stall when it covers most of the jump, else an input pause (counted)."""
        jump = jump_ns * 1e-9
        if self.stalls.between(a_prev, a_late) > 0.5 * jump_ns:
            self.counters.node_stall_gaps += 1
            self.events.add(now_ns, f"the node stalled ({jump:.3g} s late samples not taken back): time "
                            "gap, estimator re-primed (not an input pause)")
        else:
            self.counters.gaps += 1
            self.events.add(now_ns, f"input pause of {jump:.3g} s: time gap, estimator re-primed")

    def _give_back(self, vals: np.ndarray, arr: np.ndarray) -> None:
        """Return aligned-but-held samples to the front of the pending lists (arrival = completion time)."""
        for i, p in enumerate(self.queues.pending):
            p[:0] = [(float(v), int(a)) for v, a in zip(vals[i], arr, strict=True)]
