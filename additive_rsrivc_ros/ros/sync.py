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

import math
from collections.abc import Callable, Mapping
from typing import Any

from .input_queues import BYTES_PER_SAMPLE
from .input_stage import InputStage
from .order_pairing import OrderPairing
from .stamped_pairing import StampedPairing
from .sync_state import Aligned, SyncCounters, SyncSettings

__all__ = ["BYTES_PER_SAMPLE", "Aligned", "InputSync", "SyncCounters", "backlog_samples", "pause_gap_s", "settings"]


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


class InputSync(InputStage):
    """Turns per-topic message queues into aligned samples; see the module docstring.

    ``signals`` are the names in the order the pipeline wants them, e.g. ``("reference", "input", "output")``
    or ``("input", "output")`` in open loop. Its parts (besides those of :class:`.input_stage.InputStage`):
    :class:`.order_pairing.OrderPairing` or :class:`.stamped_pairing.StampedPairing` (the pairing); this class bounds
    the backlog between the topics and resynchronizes them.
    """

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
        signals = tuple(signals)
        settings = SyncSettings(stall_ns=int(stall_s * 1e9),
                                skew_ns=int((0.5 / rate_hz if skew_s is None else skew_s) * 1e9))
        super().__init__(signals, rate_hz, tuple(labels) if labels is not None else signals, max_queue,
                         settings=settings, rate_window_s=rate_window_s, rate_tolerance=rate_tolerance)
        self.stamped = stamped
        InputSync.update(self, max_backlog=max_backlog, quiet_s=quiet_s, gap_s=gap_s, hold_s=hold_s,
                         silent_s=quiet_s if silent_s is None else silent_s)
        self.order = OrderPairing(self.signals, self.rate, settings=self.settings, queues=self.inputs,
                                  counters=self.counters, events=self.event_log, stalls=self.stalls)
        self.stamps = StampedPairing(self.signals, counters=self.counters, events=self.event_log)
        self._imbalance_since: int | None = None

    # ----------------------------------------------------------------------------------------- control
    def update(self, *, silent_s: float | None = None, max_backlog: int | None = None, gap_s: float | None = None,
               quiet_s: float | None = None, hold_s: float | None = None) -> None:
        """Apply (validated) settings, at start-up and on a runtime parameter change alike: the same conversions and
        floors (``silent_s`` and the count-mismatch persistence never below a stall). None leaves a setting as is."""
        st = self.settings
        if max_backlog is not None:
            st.max_backlog = int(max_backlog)
        if gap_s is not None:
            st.gap_ns = int(gap_s * 1e9)
        if hold_s is not None:
            st.hold_ns = int(hold_s * 1e9)
        if quiet_s is not None:
            st.quiet_ns = int(quiet_s * 1e9)
        if silent_s is not None:
            st.silent_req_ns = int(silent_s * 1e9)
        # a topic may stall while the others continue: reliable DDS recovers a lost datagram only at the writer's
        # next heartbeat (Fast DDS: every 3 s); an imbalance is a count mismatch only after it outlasts that
        st.persist_ns = max(st.stall_ns, 2 * st.quiet_ns)
        # a topic behind the others is lost only after a silence longer than a stall too
        st.silent_ns = max(st.silent_req_ns, st.persist_ns)

    @property
    def pairing(self) -> str:
        """How samples are paired (the node's start-up line)."""
        return "stamped" if self.stamped else "arrival order"

    def set_time_floor(self, t_floor: float | None) -> None:
        """Emit times above ``t_floor + 1 s`` from now on (after restoring a saved estimator state)."""
        self.time_floor = self.order.time_floor = t_floor
        self.stamps.set_time_floor(t_floor)
        self.order.restart_grid()

    def _restart(self) -> None:
        """The streams lost their pairing: restart the time grid, re-align the heads (arrival order only)."""
        self.order.restart_grid()
        self.order.align_heads = not self.stamped

    def resync(self, now_ns: int, reason: str, *, count: bool = True) -> None:
        """Discard everything pending; re-align the heads and restart the time grid after a gap."""
        n_drop = self.inputs.discard_pending()
        self.counters.dropped += n_drop
        if count:
            self.counters.mismatches += 1
        self._event(now_ns, f"{reason}; {n_drop} pending messages discarded, streams resynchronized")
        self._restart()

    @property
    def arrival_is_the_clock(self) -> bool:
        """The samples' times come from their arrival (Float64 topics): an arrival rate that contradicts
        ``loop_rate_hz`` is then a wrong time scale. Header-stamped samples carry their own time."""
        return not self.stamped

    # ----------------------------------------------------------------------------------------- alignment
    def collect(self, now_ns: int, *, idle_since_ns: int = 0, ros_now_s: float = 0.0) -> Aligned | None:
        """Align what has arrived; ``idle_since_ns``: last time the executor had nothing to do (pause check)."""
        dropped = self.inputs.drain(now_ns, self.stamps.increasing if self.stamped else None)
        if self.stamped:
            got = self.stamps.take(self.pending, now_ns)
            self._bound_backlog(now_ns, [len(p) for p in self.pending])
            return got
        if dropped:                 # samples lost at a bound: the order of the streams no longer pairs them
            self.order.restart_grid()
            self.order.align_heads = True
        return self._collect_order(now_ns, idle_since_ns, ros_now_s)

    def _bound_backlog(self, now_ns: int, lens: list[int]) -> bool:
        """One topic ahead of another by more than ``max_backlog``: drop (silent partner) or resync."""
        st = self.settings
        if max(lens) - min(lens) <= st.max_backlog:
            self._imbalance_since = None
            return False
        behind = [s for s, n_ in zip(self.signals, lens, strict=True) if n_ == min(lens)]
        last = self.inputs.last_arrival_ns
        silent = [s for s, i in ((s, self.signals.index(s)) for s in behind)
                  if last[i] == 0 or now_ns - last[i] > st.silent_ns]
        if not silent:
            # executors deliver bursts topic by topic: only a lasting imbalance is a count mismatch
            if self._imbalance_since is None:
                self._imbalance_since = now_ns
            if now_ns - self._imbalance_since < st.persist_ns:
                return False
        self._imbalance_since = None
        if silent:
            n_drop = self.inputs.discard_pending()
            self.counters.dropped += n_drop
            self._event(now_ns, f"no data on {', '.join(silent)} while the other topics continue; "
                        f"{n_drop} unmatched messages discarded")
            self._restart()
        else:
            self.resync(now_ns, "count mismatch: " + ", ".join(f"{s} {n_}" for s, n_ in zip(self.signals, lens,
                                                                                           strict=True))
                        + " pending messages")
        return True

    def _collect_order(self, now_ns: int, idle_since_ns: int, ros_now_s: float) -> Aligned | None:
        if not self.order.heads_aligned():
            return None
        lens = [len(p) for p in self.pending]
        if self._bound_backlog(now_ns, lens):
            return None
        n = min(lens)
        if n == 0 or min(lens) != max(lens):
            # pause check: every topic quiet and the executor idle since -> the leftovers can never match
            last = max(self.inputs.last_arrival_ns)
            if (max(lens) > n and now_ns - last > self.settings.quiet_ns and idle_since_ns > last):
                taken = self.order.take(n, now_ns, ros_now_s) if n else None
                self.resync(now_ns, "count mismatch after all topics went quiet: "
                            + ", ".join(f"{s} +{n_ - n}" for s, n_ in zip(self.signals, lens, strict=True)))
                return taken
            if n == 0:
                return None
        return self.order.take(n, now_ns, ros_now_s)
