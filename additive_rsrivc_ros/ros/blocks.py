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

import threading
from collections.abc import Callable
from typing import Any

import numpy as np

from .block_index import DUPLICATE_MEMORY_S, RESTART_GAP_S, BlockIndex, Released
from .block_invariant import INVARIANT_WARN, ControllerInvariant
from .input_stage import InputStage
from .sync_state import Aligned, SyncSettings

__all__ = ["BLOCK_COLUMNS", "DUPLICATE_MEMORY_S", "INVARIANT_WARN", "RESTART_GAP_S", "BlockSync", "block_rows",
           "index_problem"]

LOG_EVERY_S = 5.0            # malformed blocks: at most one log line per this many seconds
MAX_INDEX = float(2 ** 53)   # integers are exact in float64 below this
BLOCK_COLUMNS = ("index", "reference", "input", "output")


class BlockSync(InputStage):
    """Block rows -> :class:`Aligned` samples by the controller's index; see the module docstring.

    The node's callback calls :meth:`enqueue` (cheap, bounded by rows); the worker's :meth:`collect` converts the
    queued messages with ``convert`` (``msg -> (rows (N, 4) | None, error)``), validates them and hands the rows to its
    :class:`.block_index.BlockIndex` (pairing by index) and :class:`.block_invariant.ControllerInvariant`. Counters of
    the per-sample path keep their meaning (``received``/``aligned`` in samples, ``dropped``: rows never given to the
    pipeline); the block-specific ones are in :meth:`extra_values`.
    """

    wake: threading.Event   # always an event here: the worker sleeps until a block arrives

    def __init__(self, rate_hz: float, *, closed_loop: bool, label: str,
                 convert: Callable[[Any], tuple[np.ndarray | None, str]], reorder_s: float = 0.05,
                 controller: Any = None, gap_s: float = 0.1, silent_s: float = 1.0, max_queue: int = 1 << 20,
                 rate_window_s: float = 2.0, rate_tolerance: float = 0.02) -> None:
        super().__init__(("block",), rate_hz, (label,), max_queue, settings=SyncSettings(),
                         rate_window_s=rate_window_s, rate_tolerance=rate_tolerance, bounded=False)
        self.update(gap_s=gap_s, silent_s=silent_s)
        self.closed_loop = bool(closed_loop)
        self.convert = convert
        self.wake = threading.Event()              # set by every enqueued message: the worker sleeps until then
        self.rows_in = self.rows_out = self.rows_shed = 0   # written by one thread each (callback / worker / callback)
        self._shed_seen = 0
        self.block = dict.fromkeys(("messages", "malformed", "duplicate_samples", "conflicting_samples",
                                    "late_samples", "missing_samples", "gaps", "restarts", "reordered"), 0)
        self.invariant = ControllerInvariant(self.rate, controller if self.closed_loop else None)
        self.index = BlockIndex(self.rate, label, max_queue=self.max_queue, reorder_s=reorder_s, counts=self.block,
                                counters=self.counters, events=self.event_log, invariant=self.invariant)
        self.last_malformed = ""
        self._malformed_logged_ns = 0
        self._malformed_since_log = 0
        self.last_block_rows = 0                   # rows of the latest valid block (its span vs stale_timeout_s)
        self._span_warned = False

    @property
    def pending(self) -> list[list[Any]]:
        """The blocks held behind a hole (one list: rows are paired by index, not per topic)."""
        return [self.index.held]

    @property
    def pairing(self) -> str:
        return "block rows paired by the controller's index"

    @property
    def invariant_relative(self) -> float:
        """Median relative residual of the controller invariant on the rows (nan: not evaluated)."""
        return self.invariant.relative

    def update(self, *, silent_s: float | None = None, max_backlog: int | None = None, gap_s: float | None = None,
               quiet_s: float | None = None, hold_s: float | None = None) -> None:
        """Settings as at start-up: the gap and the silence apply (the silence without the stall floor of Float64
        topics: rows are paired by index); backlog, quiet and hold are Float64-topic settings, unused here."""
        if gap_s is not None:
            self.settings.gap_ns = int(gap_s * 1e9)
        if silent_s is not None:
            self.settings.silent_ns = int(silent_s * 1e9)

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
        return 2 * self.max_queue * (4 * 8 + 16) + self.index.mem_k.size * 32

    # ------------------------------------------------------------------------------------------- worker side
    def set_time_floor(self, t_floor: float | None) -> None:
        """Release times above ``t_floor + 1 s`` (after restoring a saved estimator state)."""
        self.time_floor = t_floor
        self.index.set_time_floor(t_floor)

    def resync(self, now_ns: int, reason: str, *, count: bool = True) -> None:
        """Nothing to re-pair (rows are paired by index): only say what happened."""
        self._event(now_ns, reason)

    def flush(self, now_ns: int, ros_now_s: float) -> Aligned | None:
        """End of a record (offline): every held row is released now; a hole left before it is a gap."""
        out: Released = []
        self._drain_blocks(now_ns, ros_now_s, out)
        self.index.release(now_ns, ros_now_s, out, force=True)
        return self._aligned(out)

    def collect(self, now_ns: int, *, idle_since_ns: int = 0, ros_now_s: float = 0.0) -> Aligned | None:
        """Convert and check the queued blocks, release the rows whose turn has come (see the module docstring)."""
        out: Released = []
        self._drain_blocks(now_ns, ros_now_s, out)
        self.index.release(now_ns, ros_now_s, out, force=False)
        return self._aligned(out)

    def _aligned(self, out: Released) -> Aligned | None:
        if not out:
            return None
        t = np.concatenate([o[0] for o in out])
        v = np.concatenate([o[1] for o in out])
        arr = np.concatenate([o[2] for o in out])
        self.counters.aligned += t.size
        return Aligned(t, v[:, 0].copy() if self.closed_loop else None, v[:, 1].copy(), v[:, 2].copy(), arr)

    def _drain_blocks(self, now_ns: int, ros_now_s: float, out: Released) -> None:
        q = self.queues[0]
        last_arrival = self.inputs.last_arrival_ns
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
            last_arrival[0] = arrival
            self._note_block_span(rows.shape[0], now_ns)
            self.add_rows(rows, arrival, now_ns, ros_now_s, out)
        shed = self.rows_shed - self._shed_seen
        self._shed_seen += shed
        if last_arrival[0]:
            self.rates.record(0, last_arrival[0], self.counters.received[0] + self.rows_shed, now_ns)
        self._shed(now_ns, shed)

    def add_rows(self, rows: np.ndarray, arrival_ns: int, now_ns: int, ros_now_s: float, out: Released) -> None:
        """Take one valid block (index strictly increasing, integral): duplicates, restart, or rows to hold."""
        self.index.add_rows(rows, arrival_ns, now_ns, ros_now_s, out)

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
        gap_ns = self.settings.gap_ns
        return max(gap_ns, int(3 * np.median(d))) if d.size else gap_ns

    def _span_reason(self) -> str:
        span, silent = self.last_block_rows / self.rate, self.settings.silent_ns * 1e-9
        if silent <= 0.0 or span <= silent:
            return ""
        return (f"blocks of {self.last_block_rows} rows cover {span:.3g} s, more than stale_timeout_s ({silent:g} s): "
                f"the input looks silent between blocks; set stale_timeout_s above {span:.3g} s")

    def _shed(self, now_ns: int, n_drop: int) -> None:
        """Rows dropped at the callback queue's bound: counted; one event per episode (they become an index gap)."""
        overflowing = self.inputs.overflowing
        if n_drop > 0:
            self.counters.queue_dropped[0] += n_drop
            self.counters.dropped += n_drop
            if not overflowing[0]:
                self._event(now_ns, f"queue of {self.labels[0]} full ({self.max_queue} samples, "
                            f"{self.max_queue / self.rate:.3g} s): dropping the oldest blocks")
            overflowing[0] += n_drop
        elif overflowing[0] and self.rows_in - self.rows_out - self.rows_shed < self.max_queue // 2:
            self._event(now_ns, f"queue of {self.labels[0]} below its bound again; {overflowing[0]} "
                        "samples of the oldest blocks were dropped")
            overflowing[0] = 0

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

    # ------------------------------------------------------------------------------------------- reporting
    def extra_values(self) -> dict[str, Any]:
        """Block counters for the estimator status."""
        return {"malformed_messages": self.block["malformed"], **{f"block_{k}": v for k, v in self.block.items()},
                "block_held_samples": self.index.held_rows(),
                "block_invariant_relative_residual": self.invariant.relative}

    def lasting_reasons(self) -> list[str]:
        """Lasting problems of the block input (WARN reasons on the estimator status)."""
        return [r for r in (self._span_reason(), self.invariant.reason()) if r]


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
