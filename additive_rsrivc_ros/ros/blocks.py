"""Block input: r, u, y rows of the controller, paired by its sample counter (ROS-free, used by the monitor node).

One ``Float64MultiArray`` per block on ``block.topic`` (layout: docs/INTERFACE.md "Signals in", checked by
:func:`block_rows`); the index column is checked and rows become samples timed ``t = t_anchor + (index -
index_anchor) / loop_rate_hz``: arrival times never move a sample. Missing indices are a gap (``block_gaps``)
handled by the pipeline as on every path; rows after a hole wait ``block.reorder_s`` for the late block, later ones are
dropped (``block_late_samples``); rows released before with the same values are dropped (``block_duplicate_samples``),
with other values, or an index going back beyond ``DUPLICATE_MEMORY_S``, they are a controller restart
(``block_restarts``: time jumps by ``RESTART_GAP_S`` and the estimator re-primes); malformed blocks are dropped and
counted (``block_malformed``). In closed loop the invariant ``u = C_d(q)(r - y)`` ([RA-SRIVC] eq. 10) is evaluated on
released rows as a consistency check, never to re-pair them. Every queue and memory is bounded by ``max_queue`` rows.
"""

from __future__ import annotations

import math
import threading
from collections import deque
from collections.abc import Callable
from typing import Any

import numpy as np

from ..core.alignment import invariant_residual
from .sync import Aligned, InputSync

DUPLICATE_MEMORY_S = 2.0     # released rows kept to tell a retransmitted block (equal values) from a restart
RESTART_GAP_S = 1.0          # time jump after a controller restart: far above any filled short gap (re-prime)
LOG_EVERY_S = 5.0            # malformed blocks: at most one log line per this many seconds
INVARIANT_EVERY_S = 0.1      # the invariant is evaluated on the block that completes this much data since the last
INVARIANT_WARN = 1e-6        # relative invariant residual above which the block rows do not fit the controller
MAX_INDEX = float(2 ** 53)   # integers are exact in float64 below this
SKIPPED_MEMORY = 256         # declared gaps remembered to classify a late block
BLOCK_COLUMNS = ("index", "reference", "input", "output")


class BlockSync(InputSync):
    """Block rows -> :class:`Aligned` samples by the controller's index; see the module docstring.

    The node's callback calls :meth:`enqueue` (cheap, bounded); the worker's :meth:`collect` converts the queued
    messages with ``convert`` (``msg -> (rows (N, 4) | None, error)``), validates the index and releases rows.
    Counters of the per-sample path keep their meaning (``received``/``aligned`` in samples, ``dropped``: rows
    never given to the pipeline); the block-specific ones are in :meth:`extra_values`.
    """

    wake: threading.Event   # always an event here: the worker sleeps until a block arrives

    def __init__(self, rate_hz: float, *, closed_loop: bool, label: str,
                 convert: Callable[[Any], tuple[np.ndarray | None, str]], reorder_s: float = 0.05,
                 controller: Any = None, gap_s: float = 0.1, silent_s: float = 1.0, max_queue: int = 1 << 20,
                 rate_window_s: float = 2.0, rate_tolerance: float = 0.02) -> None:
        super().__init__(("output",), rate_hz, stamped=True, max_backlog=max(1, max_queue // 2), quiet_s=1.0,
                         gap_s=gap_s, hold_s=0.0, silent_s=silent_s, stall_s=0.0, max_queue=max_queue,
                         labels=(label,), rate_window_s=rate_window_s, rate_tolerance=rate_tolerance)
        self.signals = ("block",)
        self.update(silent_s=silent_s)
        self.closed_loop = bool(closed_loop)
        self.convert = convert
        self.reorder_ns = int(max(0.0, reorder_s) * 1e9)
        self.queues = [deque()]                    # (msg, arrival_ns, rows) from the callback; bounded by rows
        self.wake = threading.Event()              # set by every enqueued message: the worker sleeps until then
        self.rows_in = self.rows_out = self.rows_shed = 0   # written by one thread each (callback / worker / callback)
        self._shed_seen = 0
        self.next_k: int | None = None
        self.k_anchor = 0
        self.t_anchor: float | None = None
        self.last_t: float | None = None
        self.held: list[tuple[np.ndarray, np.ndarray, int]] = []    # (index, values (n, 3), arrival) after a hole
        self.pending = [self.held]
        self._restart_pending = False
        n_mem = max(16, int(math.ceil(DUPLICATE_MEMORY_S * self.rate)))
        self.mem_k = np.full(n_mem, -1, dtype=np.int64)   # ring of released rows: index and r, u, y
        self.mem_v = np.zeros((n_mem, 3))
        self.mem_i = 0
        self.skipped: deque[tuple[int, int]] = deque(maxlen=SKIPPED_MEMORY)
        self.block = dict.fromkeys(("messages", "malformed", "duplicate_samples", "conflicting_samples",
                                    "late_samples", "missing_samples", "gaps", "restarts", "reordered"), 0)
        self.last_malformed = ""
        self._malformed_logged_ns = 0
        self._malformed_since_log = 0
        self._den: np.ndarray | None = None
        self._num: np.ndarray | None = None
        if controller is not None and self.closed_loop:
            self._den, self._num = np.asarray(controller.den, float), np.asarray(controller.num, float)
        self._order = 0 if self._den is None or self._num is None else max(self._den.size, self._num.size) - 1
        self._tail: tuple[np.ndarray, np.ndarray] | None = None     # last released rows for the invariant
        self.invariant_relative = math.nan
        self._inv_rows = 0
        self.last_block_rows = 0                   # rows of the latest valid block (its span vs stale_timeout_s)
        self._span_warned = False

    @property
    def pairing(self) -> str:
        return "block rows paired by the controller's index"

    def update(self, *, silent_s: float | None = None, max_backlog: int | None = None, gap_s: float | None = None,
               quiet_s: float | None = None, hold_s: float | None = None) -> None:
        """Settings as at start-up: the gap and the silence apply (the silence without the stall floor of Float64
        topics: rows are paired by index); backlog, quiet and hold are Float64-topic settings, unused here."""
        if gap_s is not None:
            self.gap_ns = int(gap_s * 1e9)
        if silent_s is not None:
            self.silent_ns = int(silent_s * 1e9)

    # ------------------------------------------------------------------------------------------- callback side
    def enqueue(self, msg: Any, arrival_ns: int) -> None:
        """Executor thread: queue one message; beyond ``max_queue`` rows the oldest messages are dropped (counted)."""
        q = self.queues[0]
        n = max(1, len(msg.data) // 4)
        q.append((msg, arrival_ns, n))
        self.rows_in += n
        while self.rows_in - self.rows_out - self.rows_shed > self.max_queue and len(q) > 1:
            try:
                _, _, m = q.popleft()
            except IndexError:
                break
            self.rows_shed += m
        self.wake.set()

    def queue_bytes(self) -> int:
        """Upper bound of the memory of queued and held rows (the callback queue and rows held after a hole)."""
        return 2 * self.max_queue * (4 * 8 + 16) + self.mem_k.size * 32

    # ------------------------------------------------------------------------------------------- worker side
    def set_time_floor(self, t_floor: float | None) -> None:
        """Release times above ``t_floor + 1 s`` (after restoring a saved estimator state)."""
        self.time_floor = t_floor
        if t_floor is not None:
            self.t_anchor = None

    def resync(self, now_ns: int, reason: str, *, count: bool = True) -> None:
        """Nothing to re-pair (rows are paired by index): only say what happened."""
        self._event(now_ns, reason)

    def flush(self, now_ns: int, ros_now_s: float) -> Aligned | None:
        """End of a record (offline): every held row is released now; a hole left before it is a gap."""
        out: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self._drain_blocks(now_ns, ros_now_s, out)
        self._release(now_ns, ros_now_s, out, force=True)
        return self._aligned(out)

    def collect(self, now_ns: int, *, idle_since_ns: int = 0, ros_now_s: float = 0.0) -> Aligned | None:
        """Convert and check the queued blocks, release the rows whose turn has come (see the module docstring)."""
        out: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self._drain_blocks(now_ns, ros_now_s, out)
        self._release(now_ns, ros_now_s, out, force=False)
        return self._aligned(out)

    def _aligned(self, out: list[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> Aligned | None:
        if not out:
            return None
        t = np.concatenate([o[0] for o in out])
        v = np.concatenate([o[1] for o in out])
        arr = np.concatenate([o[2] for o in out])
        self.counters.aligned += t.size
        return Aligned(t, v[:, 0].copy() if self.closed_loop else None, v[:, 1].copy(), v[:, 2].copy(), arr)

    def _drain_blocks(self, now_ns: int, ros_now_s: float, out: list) -> None:
        q = self.queues[0]
        for _ in range(len(q)):
            msg, arrival, n = q.popleft()
            self.rows_out += n
            self.block["messages"] += 1
            rows, err = self.convert(msg)
            if rows is not None:
                err = index_problem(rows[:, 0])
            if err or rows is None:
                self._malformed(now_ns, err or "no rows")
                continue
            self.counters.received[0] += rows.shape[0]
            self.last_arrival_ns[0] = arrival
            self._note_block_span(rows.shape[0], now_ns)
            self.add_rows(rows, arrival, now_ns, ros_now_s, out)
        shed = self.rows_shed - self._shed_seen
        self._shed_seen += shed
        if self.last_arrival_ns[0]:
            pts = self._rate_pts[0]
            pts.append((self.last_arrival_ns[0], self.counters.received[0] + self.rows_shed))
            while pts and pts[0][0] < now_ns - 2 * self.rate_window_ns:
                pts.popleft()
        self._shed(now_ns, shed)

    def _note_block_span(self, n_rows: int, now_ns: int) -> None:
        """Blocks that cover more than ``stale_timeout_s`` make the input look silent between them: one log line when
        that begins (and again if it returns), and a lasting reason while it holds (:meth:`lasting_reasons`)."""
        self.last_block_rows = n_rows
        reason = self._span_reason()
        if reason and not self._span_warned:
            self._event(now_ns, reason)
        self._span_warned = bool(reason)

    @property
    def arrival_is_the_clock(self) -> bool:
        """Block indices count samples but carry no time: the arrival rate is the only check of ``loop_rate_hz``."""
        return True

    def _arrival_gap_ns(self, arrivals_ns: np.ndarray) -> int:
        """Blocks arrive once per block, not once per sample: a pause is a spacing of more than three typical
        block periods (or the data gap, if longer)."""
        d = np.diff(arrivals_ns)
        return max(self.gap_ns, int(3 * np.median(d))) if d.size else self.gap_ns

    def _span_reason(self) -> str:
        span, silent = self.last_block_rows / self.rate, self.silent_ns * 1e-9
        if silent <= 0.0 or span <= silent:
            return ""
        return (f"blocks of {self.last_block_rows} rows cover {span:.3g} s, more than stale_timeout_s ({silent:g} s): "
                f"the input looks silent between blocks; set stale_timeout_s above {span:.3g} s")

    def _shed(self, now_ns: int, n_drop: int) -> None:
        """Rows dropped at the callback queue's bound: counted; one event per episode (they become an index gap)."""
        if n_drop > 0:
            self.counters.queue_dropped[0] += n_drop
            self.counters.dropped += n_drop
            if not self._overflowing[0]:
                self._event(now_ns, f"queue of {self.labels[0]} full ({self.max_queue} samples, "
                            f"{self.max_queue / self.rate:.3g} s): dropping the oldest blocks")
            self._overflowing[0] += n_drop
        elif self._overflowing[0] and self.rows_in - self.rows_out - self.rows_shed < self.max_queue // 2:
            self._event(now_ns, f"queue of {self.labels[0]} below its bound again; {self._overflowing[0]} "
                        "samples of the oldest blocks were dropped")
            self._overflowing[0] = 0

    def _malformed(self, now_ns: int, err: str) -> None:
        """Count a malformed block; log (as an event) at most once per ``LOG_EVERY_S``."""
        self.block["malformed"] += 1
        self._malformed_since_log += 1
        self.last_malformed = err
        if not self._malformed_logged_ns or now_ns - self._malformed_logged_ns >= LOG_EVERY_S * 1e9:
            n = self._malformed_since_log
            self._event(now_ns, f"malformed block on {self.labels[0]} dropped ({err})" +
                        (f"; {n} malformed blocks since the last such line" if n > 1 else "") +
                        f"; {self.block['malformed']} in all")
            self._malformed_logged_ns = now_ns
            self._malformed_since_log = 0

    # ------------------------------------------------------------------------------------------- index logic
    def add_rows(self, rows: np.ndarray, arrival_ns: int, now_ns: int, ros_now_s: float, out: list) -> None:
        """Take one valid block (index strictly increasing, integral): duplicates, restart, or rows to hold."""
        k = rows[:, 0].astype(np.int64)
        vals = rows[:, 1:4]
        if self.next_k is None:
            self.next_k = int(k[0])
        behind = k < self.next_k
        if behind.any():
            dup, conflict, late, unknown = self._classify_behind(k[behind], vals[behind])
            if conflict or (unknown and behind.all()):
                self._restart(k, vals, arrival_ns, now_ns, ros_now_s, out, conflict, unknown)
                return
            n_drop = int(behind.sum())
            self.block["duplicate_samples"] += dup
            self.block["late_samples"] += late + unknown
            self.counters.dropped += n_drop
            if late + unknown:
                self._event(now_ns, f"{late + unknown} samples of a late block on {self.labels[0]} dropped (their "
                            "indices were already declared a gap)")
            k, vals = k[~behind], vals[~behind]
            if k.size == 0:
                return
        conflict = self._conflicts_with_held(k, vals)
        if conflict:                       # same index, other values than a block waiting behind a hole: a restart
            self._restart(k, vals, arrival_ns, now_ns, ros_now_s, out, conflict, 0)
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
                self.block["duplicate_samples"] += n
                self.counters.dropped += n
                k, vals = k[~dup], vals[~dup]
        if k.size == 0:
            return
        pos = 0
        while pos < len(self.held) and self.held[pos][0][0] < k[0]:
            pos += 1
        if pos < len(self.held):
            self.block["reordered"] += 1
        self.held.insert(pos, (k, vals, int(arrival_ns)))

    def _release(self, now_ns: int, ros_now_s: float, out: list, *, force: bool) -> None:
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
        self.block["gaps"] += 1
        self.block["missing_samples"] += n
        self.skipped.append((lo, hi))
        self._event(now_ns, f"index gap on {self.labels[0]}: {n} samples missing (index {lo}..{hi}); the estimator "
                    "sees a data gap")
        self.next_k = hi + 1

    def _emit(self, k: np.ndarray, vals: np.ndarray, arrival: int, ros_now_s: float, out: list) -> None:
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
        self._check_invariant(k, vals)
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

    def _restart(self, k: np.ndarray, vals: np.ndarray, arrival_ns: int, now_ns: int, ros_now_s: float,
                 out: list, conflict: int, unknown: int) -> None:
        """The controller's counter started a new run: release what is held, then anchor the new run after a gap."""
        self._release(now_ns, ros_now_s, out, force=True)
        why = (f"{conflict} rows reuse indices already received with other values" if conflict else
               f"the index went back from {self._next() - 1} to {int(k[0])}")
        self.block["restarts"] += 1
        self.block["conflicting_samples"] += conflict
        self._event(now_ns, f"controller restart on {self.labels[0]} ({why}): new index run from {int(k[0])}, "
                    "estimator re-primed")
        self.next_k = int(k[0])
        self.t_anchor = None
        self._restart_pending = True
        self.skipped.clear()
        self.mem_k[:] = -1
        self._tail = None
        self._hold(k, vals, arrival_ns)

    def _check_invariant(self, k: np.ndarray, vals: np.ndarray) -> None:
        """Closed loop: relative residual of ``D(q^-1) u = N(q^-1)(r - y)`` ([RA-SRIVC] eq. 10) over adjacent rows."""
        p = self._order
        if self._den is None or self._num is None:
            return
        tail, self._tail = self._tail, ((k[-p:].copy(), vals[-p:].copy()) if p else None)
        self._inv_rows += k.size
        if self._inv_rows < INVARIANT_EVERY_S * self.rate:     # a consistency check: a few times a second is enough
            return
        self._inv_rows = 0
        if tail is not None and tail[0].size and tail[0][-1] == k[0] - 1:
            k = np.concatenate((tail[0], k))
            vals = np.concatenate((tail[1], vals))
        if k.size <= p:
            return
        e, scale = invariant_residual(self._den, self._num, vals[:, 0], vals[:, 1], vals[:, 2])
        ok = (k[p:] - k[:k.size - p] == p) & np.isfinite(e) & (scale > 0)
        if ok.any():
            self.invariant_relative = float(np.median(np.abs(e[ok]) / scale[ok]))

    # ------------------------------------------------------------------------------------------- reporting
    def extra_values(self) -> dict[str, Any]:
        """Block counters for the estimator status."""
        return {"malformed_messages": self.block["malformed"], **{f"block_{k}": v for k, v in self.block.items()},
                "block_held_samples": sum(h[0].size for h in self.held),
                "block_invariant_relative_residual": self.invariant_relative}

    def lasting_reasons(self) -> list[str]:
        """Lasting problems of the block input (WARN reasons on the estimator status)."""
        span = self._span_reason()
        out = [span] if span else []
        rel = self.invariant_relative
        if math.isfinite(rel) and rel > INVARIANT_WARN:
            out.append(f"controller invariant u = C_d(q)(r - y) holds only to {rel:.2g} relative on the block rows "
                       "(rounding gives ~1e-16): check controller.numerator/denominator and the column order index, "
                       "reference, input, output")
        return out


def _same_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Per row: every value equal (NaN equal to NaN)."""
    return np.all((a == b) | (np.isnan(a) & np.isnan(b)), axis=1)


def index_problem(index: np.ndarray) -> str:
    """Why a block's index column is unusable ('' if fine): non-finite, non-integer, out of range, not increasing."""
    if np.all((index >= 0.0) & (index < MAX_INDEX) & (index == np.floor(index))) and (
            index.size < 2 or np.all(index[1:] > index[:-1])):
        return ""                               # the common case in two passes (NaN and inf fail the range test)
    if not np.all(np.isfinite(index)):
        return "non-finite index"
    if np.any(index != np.floor(index)):
        return "non-integer index"
    if np.any(index < 0) or np.any(index >= MAX_INDEX):
        return "index outside [0, 2^53)"
    if index.size > 1 and np.any(np.diff(index) <= 0):
        return "index not strictly increasing within the block"
    return ""


def block_rows(msg: Any) -> tuple[Any, str]:
    """A block message (docs/INTERFACE.md "Signals in") as an ``(N, 4)`` float64 array of rows ``index,
    reference, input, output``, or ``(None, reason)``.

    Strict: exactly two dimensions labelled ``sample`` (size N >= 1) and ``signal`` (size 4), strides row-major
    (``4 N`` and ``4``; 0 = not set is accepted), ``len(data) - data_offset == 4 N``. A column-major or transposed
    block is refused, never read with its columns mixed up. The index column is checked by
    :func:`..ros.blocks.index_problem`."""
    dims = list(msg.layout.dim)
    if len(dims) != 2:
        return None, f"layout has {len(dims)} dimensions, expected 2 (sample, signal)"
    d0, d1 = dims
    if d0.label != "sample" or d1.label != "signal":
        return None, f"dimension labels {d0.label!r}, {d1.label!r}, expected 'sample', 'signal'"
    n, off = int(d0.size), int(msg.layout.data_offset)
    if int(d1.size) != len(BLOCK_COLUMNS):
        return None, f"dimension 'signal' has size {d1.size}, expected 4 (index, reference, input, output)"
    if n < 1:
        return None, "no rows (dimension 'sample' has size 0)"
    if int(d0.stride) not in (0, 4 * n) or int(d1.stride) not in (0, 4):
        return None, f"strides {d0.stride}, {d1.stride} are not row-major ({4 * n}, 4)"
    size = len(msg.data)
    if size - off != 4 * n:
        return None, f"data holds {size - off} values after data_offset {off}, expected {4 * n} (N = {n} rows x 4)"
    data = np.frombuffer(msg.data, dtype=np.float64) if size else np.empty(0)
    return data[off:off + 4 * n].reshape(n, 4).copy(), ""
