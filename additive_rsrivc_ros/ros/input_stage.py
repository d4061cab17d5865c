"""What every input stage of the monitor has, whatever pairs its samples (ROS-free).

:class:`InputStage` is the common base of :class:`.sync.InputSync` (per-sample topics) and :class:`.blocks.BlockSync`
(block rows): its signals and labels, the shared records (:mod:`.sync_state`: counters, events, the node's stalls,
settings), the bounded queues (:class:`.input_queues.InputQueues`) and the arrival-rate check
(:class:`.arrival_rates.ArrivalRates`), and what the node reads of them (silence, rate error, reasons). A subclass
pairs the samples (:meth:`InputStage.collect`) and applies runtime settings (:meth:`InputStage.update`).
"""

from __future__ import annotations

import threading
from collections import deque
from typing import Any

import numpy as np

from .arrival_rates import ArrivalRates
from .input_queues import InputQueues
from .sync_state import Aligned, NodeStalls, SyncCounters, SyncEvents, SyncSettings


class InputStage:
    """Queues, records and checks of one input stage; see the module docstring."""

    wake: threading.Event | None = None   # block input sets it per message; None: the worker polls every period

    def __init__(self, signals: tuple[str, ...], rate_hz: float, labels: tuple[str, ...], max_queue: int, *,
                 settings: SyncSettings, rate_window_s: float, rate_tolerance: float, bounded: bool = True) -> None:
        self.signals = signals
        self.n = len(signals)
        self.rate = float(rate_hz)
        self.labels = labels
        self.max_queue = int(max_queue)
        self.settings = settings
        self.counters = SyncCounters(received=[0] * self.n, queue_dropped=[0] * self.n)
        self.event_log = SyncEvents()
        self.stalls = NodeStalls()
        self.rates = ArrivalRates(self.rate, labels, window_s=rate_window_s, tolerance=rate_tolerance,
                                  counters=self.counters, events=self.event_log, stalls=self.stalls,
                                  gap_ns=self._arrival_gap_ns)
        self.inputs = InputQueues(labels, self.rate, self.max_queue, counters=self.counters, events=self.event_log,
                                  rates=self.rates, bounded=bounded)
        self.time_floor: float | None = None

    # ----------------------------------------------------------------------------------------- what a kind does
    @property
    def pairing(self) -> str:
        """How samples are paired (the node's start-up line)."""
        raise NotImplementedError

    def update(self, *, silent_s: float | None = None, max_backlog: int | None = None, gap_s: float | None = None,
               quiet_s: float | None = None, hold_s: float | None = None) -> None:
        """Apply (validated) settings, at start-up and on a runtime parameter change alike."""
        raise NotImplementedError

    def set_time_floor(self, t_floor: float | None) -> None:
        """Emit times above ``t_floor + 1 s`` from now on (after restoring a saved estimator state)."""
        raise NotImplementedError

    def resync(self, now_ns: int, reason: str, *, count: bool = True) -> None:
        """Start the pairing afresh (a reset); ``reason`` is the event line."""
        raise NotImplementedError

    def collect(self, now_ns: int, *, idle_since_ns: int = 0, ros_now_s: float = 0.0) -> Aligned | None:
        """Pair what has arrived; ``idle_since_ns``: last time the executor had nothing to do (pause check)."""
        raise NotImplementedError

    def lasting_reasons(self) -> list[str]:
        """Lasting problems specific to the input kind (none for topics; block input: the controller invariant)."""
        return []

    def extra_values(self) -> dict[str, Any]:
        """Estimator-status values specific to the input kind (none for topics; block input: its counters)."""
        return {}

    @property
    def arrival_is_the_clock(self) -> bool:
        """The samples' times come from their arrival: an arrival rate that contradicts ``loop_rate_hz`` is then a
        wrong time scale."""
        raise NotImplementedError

    def _arrival_gap_ns(self, arrivals_ns: np.ndarray) -> int:
        """Longest arrival spacing that is not a pause of the topic (one message per sample: the data gap)."""
        return self.settings.gap_ns

    # ----------------------------------------------------------------------------------------- the parts' state
    @property
    def queues(self) -> list[deque[Any]]:
        """The callback queues, one per signal (the callbacks append here)."""
        return self.inputs.queues

    @property
    def overflow(self) -> list[int]:
        """Per signal: items the callback's full deque dropped (counted by the callback)."""
        return self.inputs.overflow

    @property
    def pending(self) -> list[list[Any]]:
        """Per signal: drained samples waiting for their partners."""
        return self.inputs.pending

    @property
    def events(self) -> deque[str]:
        """The last event lines (one per input episode)."""
        return self.event_log.lines

    @property
    def n_events(self) -> int:
        return self.event_log.count

    @property
    def last_event_ns(self) -> int:
        return self.event_log.last_ns

    @property
    def rate_mismatch(self) -> dict[str, float]:
        """Label -> measured arrival rate (Hz) while mismatched."""
        return self.rates.mismatch

    @property
    def measured_rate(self) -> list[float]:
        return self.rates.measured

    @property
    def expected_rate(self) -> float:
        return self.rates.expected

    @property
    def rate_window_ns(self) -> int:
        return self.rates.window_ns

    # ----------------------------------------------------------------------------------------- records and checks
    def _event(self, now_ns: int, msg: str) -> None:
        self.event_log.add(now_ns, msg)

    def queue_bytes(self) -> int:
        """Upper bound of the memory the queued samples take (both bounded stages of every topic)."""
        return self.inputs.queue_bytes()

    def queue_reasons(self) -> list[str]:
        """Topics whose queue is full in an open episode: one WARN reason each."""
        return self.inputs.reasons()

    def latest_arrival(self, i: int) -> int:
        """Arrival (ns) of topic ``i``'s newest message, including messages the worker has not drained yet."""
        return self.inputs.latest_arrival(i)

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
        self.stalls.note(start_ns, end_ns)

    def check_rates(self, now_ns: int, time_scale: float = 1.0) -> list[str]:
        """Arrival rate of each topic over the last ``rate_window_s`` vs ``rate_hz * time_scale`` (the speed of
        the sample clock, 1 without sim time); returns the newly mismatched topics' one-line reasons."""
        return self.rates.check(now_ns, time_scale)

    @property
    def rate_error(self) -> str:
        """One line when the arrival rate of an input whose arrival is its clock contradicts ``loop_rate_hz`` (the
        model's time scale would be wrong: nothing is published then), else ``''``."""
        if not self.rate_mismatch or not self.arrival_is_the_clock:
            return ""
        label, rate = next(iter(self.rate_mismatch.items()))
        return (f"loop_rate_hz disagrees with the data's timing ({self.rate_reason(label, rate, self.expected_rate)}):"
                " no estimate is published until they agree")

    def rate_reason(self, label: str, rate: float, expected: float | None = None) -> str:
        """One line: ``arrival rate 2048 Hz on /plant_output, loop_rate_hz 4096``."""
        return self.rates.reason(label, rate, expected)
