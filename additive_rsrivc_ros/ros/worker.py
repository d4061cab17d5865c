"""The estimation worker of the monitor node: aligns what arrived and feeds it to the pipeline.

The worker thread wakes every ``block_period_s`` (block input: per block, at most once per ``block.batch_s``),
lets the input stage (:mod:`.sync`, :mod:`.blocks`) align the queued samples, pushes them to
:class:`..core.pipeline.MonitorPipeline` (validation, recursive additive SRIVC of [RA-SRIVC] Algorithm 2, fault logic)
and hands the reports to the publisher thread (:mod:`.publishing`). Once a second it checks the graph (wrong message
types), its CPU share and the arrival rates. It measures its own loop: steps further apart than ``STALL_NS`` are
worker stalls; the executor's stalls are reported by :func:`.monitor_node.spin` (:meth:`WorkerMixin.note_stall`).
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from .channel import ChannelState, RingStats
from .publishing import MODES_QUEUE
from .sync import Aligned, InputSync

if TYPE_CHECKING:
    from ..config import MonitorConfig

STALL_NS = 250_000_000     # the executor or the worker not running for this long is a stall of the node itself
BLOCK_IDLE_S = 0.05          # block input: longest worker sleep without a new block (reorder timeouts, rate checks)


class WorkerMixin(ChannelState):
    """The estimation worker and its statistics (part of :class:`.monitor_node.MonitorNode`)."""

    def _reset_stats(self) -> None:
        self.delays_ms = RingStats()
        self._delay_cache = (math.nan, math.nan, math.nan)
        self._delay_cache_ns = 0
        self._busy_s = 0.0
        self._data_s = 0.0
        self._cpu0 = (time.process_time(), time.monotonic())
        self._cpu_fraction = math.nan
        self._malformed: dict[str, int] = {}
        self._wrong_types: list[str] = []
        self._errors = 0
        self._last_error = ""
        self._next_graph_ns = 0
        self._latest_report = None           # newest pipeline report (worker -> publisher)
        # every report's (K, 6) estimate for ~/modes, in order (a cheap message: none is coalesced unless the
        # publisher falls this far behind; /diagnostics is composed once per cycle from the newest report)
        self._modes_queue: deque = deque(maxlen=MODES_QUEUE)
        self._reports_made = 0
        self._reports_published = 0
        self._snapshot = (None, None)        # (last report, modal) the publisher can always use
        self._push_started_ns = 0
        self._last_step_ns = 0
        self.node_stalls = 0                 # executor stalls (the node did not look at its inputs)
        self.node_stall_max_s = 0.0
        self.worker_stalls = 0               # worker steps further apart than STALL_NS (GC, compile, ...)
        self.worker_stall_max_s = 0.0
        self._clock_pts: list[tuple[int, float]] = []

    def _configure_runtime(self, cfg: MonitorConfig, values: Mapping[str, Any]) -> None:
        """The input stage and the worker/publisher periods of a configuration; statistics start afresh."""
        sync = self.sync = self._make_sync(cfg, values)
        self._use_sim_time = bool(self.parameter_value("use_sim_time"))
        t_last = self.configured_pipeline().t_last
        if t_last is not None:
            sync.set_time_floor(t_last)
        self._stale_timeout_s = values["stale_timeout_s"]
        self._publish_period_s = 1.0 / cfg.publish_rate_hz
        self._diag_period_s = values["diagnostics_period_s"]
        self._hardware_id = values["hardware_id"]
        self._block_period_s = values["block_period_s"]
        self._block_batch_s, self._block_step_due = values["block.batch_s"], 0.0
        self._reset_stats()

    def _run_worker(self) -> None:
        wake = self.configured_sync().wake   # block input: woken per message, not polled every period
        while not (self._stop.wait(self._block_period_s) if wake is None else self._wait_block(wake)):
            self.guarded_step()

    def guarded_step(self) -> None:
        """One worker step (:meth:`step`); an exception is counted and logged once, never raised."""
        try:
            self.step()
        except Exception as exc:  # noqa: BLE001 - the node must keep running; the error is reported
            self._errors += 1
            msg = f"{type(exc).__name__}: {exc}"
            if msg != self._last_error:
                self.get_logger().error(f"estimation step failed ({msg}); continuing")
            self._last_error = msg
        finally:
            self._push_started_ns = 0

    def _wait_block(self, wake: threading.Event) -> bool:
        """Block input: sleep until a block arrives (or ``BLOCK_IDLE_S`` for timeouts, rates, the graph check),
        but step at most once per ``block.batch_s`` so that several blocks share one pipeline call; True when the
        worker is to stop. (Polling every 2 ms cost 0.05 core idle; each pipeline call has a fixed cost.)"""
        rest = self._block_step_due - time.monotonic()
        if rest > 0.0 and self._stop.wait(rest):
            return True
        wake.wait(BLOCK_IDLE_S)
        wake.clear()
        self._block_step_due = time.monotonic() + self._block_batch_s
        return self._stop.is_set()

    def _ros_now_s(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def note_stall(self, start_ns: int, end_ns: int) -> None:
        """The executor did not run from ``start_ns`` to ``end_ns`` (called by :func:`.monitor_node.spin`)."""
        self.node_stalls += 1
        self.node_stall_max_s = max(self.node_stall_max_s, (end_ns - start_ns) * 1e-9)
        sync = self.sync
        if sync is not None:
            sync.note_stall(start_ns, end_ns)

    def step(self) -> None:
        """Align what arrived and feed it to the pipeline; the publisher thread publishes (never this one)."""
        now = time.monotonic_ns()
        if self._last_step_ns and now - self._last_step_ns > STALL_NS:
            self.worker_stalls += 1
            self.worker_stall_max_s = max(self.worker_stall_max_s, (now - self._last_step_ns) * 1e-9)
        self._last_step_ns = now
        with self.lock:
            sync, pipe = self.sync, self.pipeline
            if sync is None or pipe is None:
                return
            n_ev = sync.n_events
            blk = sync.collect(now, idle_since_ns=self.idle_since_ns, ros_now_s=self._ros_now_s())
            if blk is not None:
                self._push(blk)
            if now >= self._next_graph_ns:
                self._once_per_second(now, sync)
            self._log_events(sync, n_ev)
        self._last_step_ns = time.monotonic_ns()

    def _push(self, blk: Aligned) -> None:
        """Feed aligned samples to the pipeline; record timing and delays, queue the reports, log its notices."""
        pipe = self.configured_pipeline()
        was_init = pipe.initialized
        c0 = time.perf_counter()
        self._push_started_ns = time.monotonic_ns()
        reports = pipe.push(blk.t, blk.r, blk.u, blk.y)
        self._push_started_ns = 0
        self._busy_s += time.perf_counter() - c0
        self._data_s += len(blk) / self.configured_cfg().loop_rate_hz
        if was_init and pipe.initialized:
            self.delays_ms.extend((time.monotonic_ns() - blk.arrival_ns) * 1e-6)
        if reports:
            self._reports_made += len(reports)
            t0 = pipe.t0 or 0.0                # the data time of a report: origin + time since the first sample
            # ~/modes once K is known; none while loop_rate_hz contradicts the samples' stamps (a wrong time scale)
            self._modes_queue.extend((t0 + r.time_s, r.modal) for r in reports
                                     if r.K and not r.health.get("time_scale"))
            self._latest_report = reports[-1]
            self._snapshot = (reports[-1], reports[-1].modal)
        for note in (n for r in reports for n in r.notices):   # automatic start: found / failed
            if pipe.K:
                self.get_logger().info(note)
            else:
                self.get_logger().warning(note)

    def _log_events(self, sync: InputSync, n_ev: int) -> None:
        """Log the sync events raised since ``n_ev`` (each is one line, once per episode)."""
        new = sync.n_events - n_ev
        if new > 0:
            for ev in list(sync.events)[-min(new, len(sync.events)):]:
                self.get_logger().warning(f"input: {ev}")

    def _once_per_second(self, now: int, sync: InputSync) -> None:
        """Graph (wrong types), CPU, arrival rates."""
        self._next_graph_ns = now + 1_000_000_000
        self._check_graph()
        c = (time.process_time(), time.monotonic())
        if c[1] > self._cpu0[1]:
            self._cpu_fraction = (c[0] - self._cpu0[0]) / (c[1] - self._cpu0[1])
        self._cpu0 = c
        sync.check_rates(now, self._clock_speed(now))

    def _clock_speed(self, now: int) -> float:
        """Speed of the node clock vs wall time over the rate window (1 without sim time; nan when the sim
        clock does not advance: the rate check is then skipped)."""
        if not self._use_sim_time:
            return 1.0
        self._clock_pts.append((now, self._ros_now_s()))
        window_ns = self.configured_sync().rate_window_ns
        lo = now - window_ns
        while len(self._clock_pts) > 2 and self._clock_pts[1][0] <= lo:
            self._clock_pts.pop(0)
        (a0, r0), (a1, r1) = self._clock_pts[0], self._clock_pts[-1]
        if a1 - a0 < 0.5 * window_ns or r1 <= r0:
            return math.nan
        return (r1 - r0) / ((a1 - a0) * 1e-9)
