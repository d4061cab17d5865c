"""The controller's index of block rows: duplicates, late rows, holes, restarts and the time grid (ROS-free).

Rows become samples timed ``t = t_anchor + (index - index_anchor) / loop_rate_hz``: arrival times never move a
sample. Missing indices are a gap (``block_gaps``); rows after a hole wait ``block.reorder_s`` for the late block, later
ones are dropped (``block_late_samples``); rows released before with the same values are dropped
(``block_duplicate_samples``), with other values, or an index going back beyond ``DUPLICATE_MEMORY_S``, they are a
controller restart (``block_restarts``: time jumps by ``RESTART_GAP_S`` and the estimator re-primes). Every memory is
bounded by ``max_queue`` rows.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from .block_invariant import ControllerInvariant
from .sync_state import SyncCounters, SyncEvents

DUPLICATE_MEMORY_S = 2.0     # released rows kept to tell a retransmitted block (equal values) from a restart
RESTART_GAP_S = 1.0          # time jump after a controller restart: far above any filled short gap (re-prime)
SKIPPED_MEMORY = 256         # declared gaps remembered to classify a late block
Released = list[tuple[np.ndarray, np.ndarray, np.ndarray]]      # (t, values (n, 3), arrival ns) per released run


class BlockIndex:
    """Rows of valid blocks -> released ``(t, values, arrival)`` runs by the controller's index; see the module
    docstring. ``counts`` are the block counters of the estimator status (shared with :class:`.blocks.BlockSync`)."""

    def __init__(self, rate_hz: float, label: str, *, max_queue: int, reorder_s: float, counts: dict[str, int],
                 counters: SyncCounters, events: SyncEvents, invariant: ControllerInvariant) -> None:
        self.rate = float(rate_hz)
        self.label = label
        self.max_queue = int(max_queue)
        self.reorder_ns = int(max(0.0, reorder_s) * 1e9)
        self.counts = counts
        self.counters = counters
        self.events = events
        self.invariant = invariant
        self.time_floor: float | None = None
        self.next_k: int | None = None
        self.k_anchor = 0
        self.t_anchor: float | None = None
        self.last_t: float | None = None
        self.held: list[tuple[np.ndarray, np.ndarray, int]] = []    # (index, values (n, 3), arrival) after a hole
        self._restart_pending = False
        n_mem = max(16, int(math.ceil(DUPLICATE_MEMORY_S * self.rate)))
        self.mem_k = np.full(n_mem, -1, dtype=np.int64)   # ring of released rows: index and r, u, y
        self.mem_v = np.zeros((n_mem, 3))
        self.mem_i = 0
        self.skipped: deque[tuple[int, int]] = deque(maxlen=SKIPPED_MEMORY)

    def set_time_floor(self, t_floor: float | None) -> None:
        """Release times above ``t_floor + 1 s`` (after restoring a saved estimator state)."""
        self.time_floor = t_floor
        if t_floor is not None:
            self.t_anchor = None

    def held_rows(self) -> int:
        return sum(h[0].size for h in self.held)

    def add_rows(self, rows: np.ndarray, arrival_ns: int, now_ns: int, ros_now_s: float, out: Released) -> None:
        """Take one valid block (index strictly increasing, integral): duplicates, restart, or rows to hold."""
        k = rows[:, 0].astype(np.int64)
        vals = rows[:, 1:4]
        if self.next_k is None:
            self.next_k = int(k[0])
        behind = k < self.next_k
        if behind.any():
            dup, conflict, late, unknown = self._classify_behind(k[behind], vals[behind])
            if conflict or (unknown and behind.all()):
                self.restart(k, vals, arrival_ns, now_ns, ros_now_s, out, conflict, unknown)
                return
            n_drop = int(behind.sum())
            self.counts["duplicate_samples"] += dup
            self.counts["late_samples"] += late + unknown
            self.counters.dropped += n_drop
            if late + unknown:
                self.events.add(now_ns, f"{late + unknown} samples of a late block on {self.label} dropped (their "
                            "indices were already declared a gap)")
            k, vals = k[~behind], vals[~behind]
            if k.size == 0:
                return
        conflict = self._conflicts_with_held(k, vals)
        if conflict:                       # same index, other values than a block waiting behind a hole: a restart
            self.restart(k, vals, arrival_ns, now_ns, ros_now_s, out, conflict, 0)
            return
        self._hold(k, vals, arrival_ns)

    def _conflicts_with_held(self, k: np.ndarray, vals: np.ndarray) -> int:
        """Rows whose index a held block (waiting behind a hole) has with other values."""
        n = 0
        for hk, hv, _ in self.held:
            common, ia, ib = np.intersect1d(k, hk, assume_unique=True, return_indices=True)
            if common.size:
                n += int(np.sum(~_same_rows(vals[ia], hv[ib])))
        return n

    def _classify_behind(self, k: np.ndarray, vals: np.ndarray) -> tuple[int, int, int, int]:
        """Rows below the next expected index: (duplicates, conflicting, late, unknown) counts.

        Duplicate: the index was released with the same values; conflicting: released with other values; late: never
        released but within the duplicate memory's span (a declared gap, or before the first released row); unknown:
        before that span (the counter went back by a lot)."""
        order = np.argsort(self.mem_k)
        mk = self.mem_k[order]
        j = np.clip(np.searchsorted(mk, k), 0, mk.size - 1)
        seen = mk[j] == k
        same = np.zeros(k.size, dtype=bool)
        if seen.any():
            same[seen] = _same_rows(self.mem_v[order[j[seen]]], vals[seen])
        in_gap = np.zeros(k.size, dtype=bool)
        for lo, hi in self.skipped:
            in_gap |= (k >= lo) & (k <= hi)
        late = ~seen & (in_gap | (k >= self._next() - self.mem_k.size))
        return (int(same.sum()), int((seen & ~same).sum()), int(late.sum()), int((~seen & ~late).sum()))

    def _hold(self, k: np.ndarray, vals: np.ndarray, arrival_ns: int) -> None:
        """Insert rows at or after the next expected index into the held list (sorted, no index twice)."""
        for hk, _, _ in self.held:
            dup = (k >= hk[0]) & (k <= hk[-1])
            if dup.any():
                dup &= np.isin(k, hk)
                n = int(dup.sum())
                self.counts["duplicate_samples"] += n
                self.counters.dropped += n
                k, vals = k[~dup], vals[~dup]
        if k.size == 0:
            return
        pos = 0
        while pos < len(self.held) and self.held[pos][0][0] < k[0]:
            pos += 1
        if pos < len(self.held):
            self.counts["reordered"] += 1
        self.held.insert(pos, (k, vals, int(arrival_ns)))

    def release(self, now_ns: int, ros_now_s: float, out: Released, *, force: bool) -> None:
        """Release held rows from the next expected index on; a hole waits ``reorder_s`` (or ``force``)."""
        while self.held:
            k, vals, arrival = self.held[0]
            if k[0] > self._next():
                held_rows = sum(h[0].size for h in self.held)
                oldest = min(h[2] for h in self.held)
                if not (force or now_ns - oldest >= self.reorder_ns or held_rows > self.max_queue):
                    return
                self._gap(self._next(), int(k[0]) - 1, now_ns)
            self.held.pop(0)
            keep = k >= self._next()            # a later block may have overlapped an earlier held one
            k, vals = k[keep], vals[keep]
            if k.size == 0:
                continue
            holes = np.flatnonzero(np.diff(k) > 1)
            for j in holes:                    # rows missing inside one block: a gap at once (nothing can fill it)
                self._gap(int(k[j]) + 1, int(k[j + 1]) - 1, now_ns)
            self._emit(k, vals, arrival, ros_now_s, out)

    def _next(self) -> int:
        """The next expected index (known from the first block on)."""
        if self.next_k is None:
            raise RuntimeError("no block received yet: no expected index")
        return self.next_k

    def _gap(self, lo: int, hi: int, now_ns: int) -> None:
        n = hi - lo + 1
        self.counts["gaps"] += 1
        self.counts["missing_samples"] += n
        self.skipped.append((lo, hi))
        self.events.add(now_ns, f"index gap on {self.label}: {n} samples missing (index {lo}..{hi}); the estimator "
                    "sees a data gap")
        self.next_k = hi + 1

    def _emit(self, k: np.ndarray, vals: np.ndarray, arrival: int, ros_now_s: float, out: Released) -> None:
        """Rows -> times on the index grid; remember them for duplicate checks; check the invariant."""
        if self.t_anchor is None:
            t0 = ros_now_s
            if self.time_floor is not None:
                t0 = max(t0, self.time_floor + 1.0)
            if self.last_t is not None:
                t0 = max(t0, self.last_t + (RESTART_GAP_S if self._restart_pending else 0.0))
            self.t_anchor, self.k_anchor = t0, int(k[0])
            self._restart_pending = False
        t = self.t_anchor + (k - self.k_anchor).astype(np.float64) / self.rate
        if self.last_t is not None and t[0] <= self.last_t:   # a new anchor below an old time: keep times increasing
            t = t + (self.last_t - t[0]) + 1.0 / self.rate
        self.last_t = float(t[-1])
        self.next_k = int(k[-1]) + 1
        self._remember(k, vals)
        self.invariant.check(k, vals)
        out.append((t, vals.astype(np.float64, copy=True), np.full(k.size, arrival, dtype=np.int64)))

    def _remember(self, k: np.ndarray, vals: np.ndarray) -> None:
        """Keep released rows for the duplicate check: the last ``DUPLICATE_MEMORY_S``, and at least the last two of
        the largest blocks seen (a block of more than ``DUPLICATE_MEMORY_S`` sent again after its release, or one
        overlapping two released blocks, must still be recognized as released rows, not as a counter that went
        back: a controller restart), at most ``max_queue`` rows."""
        n, m = k.size, self.mem_k.size
        want = min(2 * n, max(self.max_queue, m))
        if want > m:                       # grow the ring, oldest row first, so that the oldest is overwritten first
            order = (self.mem_i + np.arange(m)) % m
            self.mem_k = np.concatenate((self.mem_k[order], np.full(want - m, -1, dtype=np.int64)))
            self.mem_v = np.concatenate((self.mem_v[order], np.zeros((want - m, 3))))
            self.mem_i, m = m, want
        idx = (self.mem_i + np.arange(min(n, m))) % m
        self.mem_k[idx], self.mem_v[idx] = k[-m:], vals[-m:]
        self.mem_i = int((self.mem_i + min(n, m)) % m)

    def restart(self, k: np.ndarray, vals: np.ndarray, arrival_ns: int, now_ns: int, ros_now_s: float,
                 out: Released, conflict: int, unknown: int) -> None:
        """The controller's counter started a new run: release what is held, then anchor the new run after a gap."""
        self.release(now_ns, ros_now_s, out, force=True)
        why = (f"{conflict} rows reuse indices already received with other values" if conflict else
               f"the index went back from {self._next() - 1} to {int(k[0])}")
        self.counts["restarts"] += 1
        self.counts["conflicting_samples"] += conflict
        self.events.add(now_ns, f"controller restart on {self.label} ({why}): new index run from {int(k[0])}, "
                    "estimator re-primed")
        self.next_k = int(k[0])
        self.t_anchor = None
        self._restart_pending = True
        self.skipped.clear()
        self.mem_k[:] = -1
        self.invariant.forget_tail()
        self._hold(k, vals, arrival_ns)


def _same_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Per row: every value equal (NaN equal to NaN)."""
    return np.all((a == b) | (np.isnan(a) & np.isnan(b)), axis=1)
