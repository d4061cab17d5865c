"""Bounded per-topic queues of an input stage: what the callbacks append, what the worker drains (ROS-free).

Two bounded stages per topic: the callback's deque (``max_queue`` samples; a full deque drops its oldest item and the
callback counts it in :attr:`InputQueues.overflow`) and the worker's pending list (trimmed to ``max_queue``). Drops
at either bound are counted per topic; one event when an episode starts and one when it ends.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from typing import Any

from .arrival_rates import ArrivalRates
from .sync_state import SyncCounters, SyncEvents

# bytes one queued sample costs at most: a 2- or 3-tuple (56-64 B), a float (24 B), one or two ints (<= 36 B
# each), a deque/list slot (8 B); measured with tracemalloc in test/test_node_sync.py
BYTES_PER_SAMPLE = 200

Filter = Callable[[int, list[tuple[Any, ...]], int], list[tuple[Any, ...]]]


class InputQueues:
    """The callback deques and pending lists of the topics ``labels``; see the module docstring."""

    def __init__(self, labels: tuple[str, ...], rate_hz: float, max_queue: int, *, counters: SyncCounters,
                 events: SyncEvents, rates: ArrivalRates, bounded: bool = True) -> None:
        self.labels = labels
        self.rate = float(rate_hz)
        self.max_queue = int(max_queue)
        self.counters = counters
        self.events = events
        self.rates = rates
        n = len(labels)
        # callbacks append here; a full deque drops its oldest item, the callback counts it in `overflow` (not
        # `bounded`: the callback bounds the queue itself, e.g. block messages by their rows)
        self.queues: list[deque[Any]] = [deque(maxlen=self.max_queue if bounded else None) for _ in range(n)]
        self.overflow = [0] * n
        self._overflow_seen = [0] * n
        self.overflowing = [0] * n          # messages dropped in the current episode (0: none open)
        self.pending: list[list[Any]] = [[] for _ in range(n)]
        self.last_arrival_ns = [0] * n

    def drain(self, now_ns: int, keep: Filter | None = None) -> bool:
        """Move what the callbacks queued to the pending lists (``keep(i, items, now_ns)`` filters a topic's items);
        count arrivals, rates and drops. True when samples were dropped at a bound (the streams lost their pairing)."""
        dropped = False
        for i, q in enumerate(self.queues):
            m = len(q)
            lost = self.overflow[i] - self._overflow_seen[i]
            self._overflow_seen[i] += lost
            if m:
                items = [q.popleft() for _ in range(m)]
                self.counters.received[i] += m + lost
                self.last_arrival_ns[i] = items[-1][1]
                self.rates.record(i, items[-1][1], self.counters.received[i], now_ns)
                if keep is not None:
                    items = keep(i, items, now_ns)
                self.pending[i].extend(items)
            excess = len(self.pending[i]) - self.max_queue
            if excess > 0:
                del self.pending[i][:excess]
            dropped |= self._drops(i, lost + max(excess, 0), now_ns)
        return dropped

    def _drops(self, i: int, n_drop: int, now_ns: int) -> bool:
        """Count oldest-dropped samples of topic ``i``; one event when an episode starts and one when it ends."""
        if n_drop > 0:
            self.counters.queue_dropped[i] += n_drop
            self.counters.dropped += n_drop
            if not self.overflowing[i]:
                self.events.add(now_ns, f"queue of {self.labels[i]} full ({self.max_queue} samples, "
                                f"{self.max_queue / self.rate:.3g} s): dropping the oldest messages")
            self.overflowing[i] += n_drop
            return True
        if self.overflowing[i] and len(self.pending[i]) + len(self.queues[i]) < self.max_queue // 2:
            self.events.add(now_ns, f"queue of {self.labels[i]} below its bound again; {self.overflowing[i]} "
                            "oldest messages were dropped")
            self.overflowing[i] = 0
        return False

    def discard_pending(self) -> int:
        """Empty every pending list; returns how many samples were discarded."""
        n_drop = sum(len(p) for p in self.pending)
        self.pending = [[] for _ in self.pending]
        return n_drop

    def queue_bytes(self) -> int:
        """Upper bound of the memory the queued samples take (both bounded stages of every topic)."""
        return 2 * len(self.queues) * self.max_queue * BYTES_PER_SAMPLE

    def reasons(self) -> list[str]:
        """Topics whose queue is full in an open episode: one WARN reason each."""
        return [f"queue of {lb} full: dropping the oldest messages ({n} so far)"
                for lb, n, ov in zip(self.labels, self.counters.queue_dropped, self.overflowing, strict=True) if ov]

    def latest_arrival(self, i: int) -> int:
        """Arrival (ns) of topic ``i``'s newest message, including messages the worker has not drained yet."""
        try:
            return max(self.last_arrival_ns[i], self.queues[i][-1][1])
        except IndexError:
            return self.last_arrival_ns[i]
