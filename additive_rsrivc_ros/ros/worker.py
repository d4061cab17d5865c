"""The estimation worker of a monitor channel: aligns what arrived and feeds it to the pipeline.

The worker thread wakes every ``block_period_s`` (block input: per block, at most once per ``block.batch_s``),
lets the input stage (:mod:`.sync`, :mod:`.blocks`) align the queued samples, pushes them to
:class:`..core.pipeline.MonitorPipeline` (validation, recursive additive SRIVC of [RA-SRIVC] Algorithm 2, fault logic)
and hands the reports to the publisher thread (:mod:`.publishing`) through the :class:`.channel.Outbox`. Once a
second it checks the graph (wrong message types), its CPU share and the arrival rates. It measures its own loop: steps
further apart than ``STALL_NS`` are worker stalls; the executor's stalls are reported by :func:`.monitor_node.spin`
(:meth:`Worker.note_stall`).
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable

from .channel import ChannelContext, ChannelCore, ChannelSettings, ChannelStats, Outbox
from .input_stage import InputStage
from .sync_state import Aligned

STALL_NS = 250_000_000     # the executor or the worker not running for this long is a stall of the node itself
BLOCK_IDLE_S = 0.05          # block input: longest worker sleep without a new block (reorder timeouts, rate checks)


class Worker:
    """The estimation worker's steps and its own timing (a part of :class:`.channel_parts.ChannelParts`);
    ``check_graph`` looks for topics of the channel carrying another message type (once a second)."""

    def __init__(self, ctx: ChannelContext, core: ChannelCore, settings: ChannelSettings, stats: ChannelStats,
                 outbox: Outbox, check_graph: Callable[[], None]) -> None:
        self.ctx = ctx
        self.core = core
        self.settings = settings
        self.stats = stats
        self.outbox = outbox
        self.check_graph = check_graph
        self.reset()

    def reset(self) -> None:
        """The worker's own timing starts afresh (a new configuration)."""
        self._cpu0 = (time.process_time(), time.monotonic())
        self._next_graph_ns = 0
        self._last_step_ns = 0
        self._block_step_due = 0.0
        self._clock_pts: list[tuple[int, float]] = []

    def run(self, stop: threading.Event) -> None:
        """The worker thread: a step every ``block_period_s`` (block input: per block) until ``stop``."""
        wake = self.core.configured_sync().wake   # block input: woken per message, not polled every period
        while not (stop.wait(self.settings.block_period_s) if wake is None else self._wait_block(wake, stop)):
            self.guarded_step()

    def guarded_step(self) -> None:
        """One worker step (:meth:`step`); an exception is counted and logged once, never raised."""
        stats = self.stats
        try:
            self.step()
        except Exception as exc:  # noqa: BLE001 - the node must keep running; the error is reported
            stats.errors += 1
            msg = f"{type(exc).__name__}: {exc}"
            if msg != stats.last_error:
                self.ctx.logger.error(f"estimation step failed ({msg}); continuing")
            stats.last_error = msg
        finally:
            stats.push_started_ns = 0

    def _wait_block(self, wake: threading.Event, stop: threading.Event) -> bool:
        """Block input: sleep until a block arrives (or ``BLOCK_IDLE_S`` for timeouts, rates, the graph check),
        but step at most once per ``block.batch_s`` so that several blocks share one pipeline call; True when the
        worker is to stop. (Polling every 2 ms cost 0.05 core idle; each pipeline call has a fixed cost.)"""
        rest = self._block_step_due - time.monotonic()
        if rest > 0.0 and stop.wait(rest):
            return True
        wake.wait(BLOCK_IDLE_S)
        wake.clear()
        self._block_step_due = time.monotonic() + self.settings.block_batch_s
        return stop.is_set()

    def note_stall(self, start_ns: int, end_ns: int) -> None:
        """The executor did not run from ``start_ns`` to ``end_ns`` (called by :func:`.monitor_node.spin`)."""
        stats = self.stats
        stats.node_stalls += 1
        stats.node_stall_max_s = max(stats.node_stall_max_s, (end_ns - start_ns) * 1e-9)
        sync = self.core.sync
        if sync is not None:
            sync.note_stall(start_ns, end_ns)

    def step(self) -> None:
        """Align what arrived and feed it to the pipeline; the publisher thread publishes (never this one)."""
        now = time.monotonic_ns()
        stats = self.stats
        if self._last_step_ns and now - self._last_step_ns > STALL_NS:
            stats.worker_stalls += 1
            stats.worker_stall_max_s = max(stats.worker_stall_max_s, (now - self._last_step_ns) * 1e-9)
        self._last_step_ns = now
        core = self.core
        with core.lock:
            sync, pipe = core.sync, core.pipeline
            if sync is None or pipe is None:
                return
            n_ev = sync.n_events
            blk = sync.collect(now, idle_since_ns=self.ctx.activity.idle_since_ns, ros_now_s=self.ctx.ros_now_s())
            if blk is not None:
                self._push(blk)
            if now >= self._next_graph_ns:
                self._once_per_second(now, sync)
            self.log_events(sync, n_ev)
        self._last_step_ns = time.monotonic_ns()

    def _push(self, blk: Aligned) -> None:
        """Feed aligned samples to the pipeline; record timing and delays, queue the reports, log its notices."""
        pipe = self.core.configured_pipeline()
        stats, outbox = self.stats, self.outbox
        was_init = pipe.initialized
        c0 = time.perf_counter()
        stats.push_started_ns = time.monotonic_ns()
        reports = pipe.push(blk.t, blk.r, blk.u, blk.y)
        stats.push_started_ns = 0
        stats.busy_s += time.perf_counter() - c0
        stats.data_s += len(blk) / self.core.configured_cfg().loop_rate_hz
        if was_init and pipe.initialized:
            stats.delays_ms.extend((time.monotonic_ns() - blk.arrival_ns) * 1e-6)
        if reports:
            outbox.reports_made += len(reports)
            t0 = pipe.t0 or 0.0                # the data time of a report: origin + time since the first sample
            # ~/modes once K is known; none while loop_rate_hz contradicts the samples' stamps (a wrong time scale)
            outbox.modes_queue.extend((t0 + r.time_s, r.modal) for r in reports
                                      if r.K and not r.health.get("time_scale"))
            outbox.latest_report = reports[-1]
            outbox.snapshot = (reports[-1], reports[-1].modal)
        for note in (n for r in reports for n in r.notices):   # automatic start: found / failed
            if pipe.K:
                self.ctx.logger.info(note)
            else:
                self.ctx.logger.warning(note)

    def log_events(self, sync: InputStage, n_ev: int) -> None:
        """Log the sync events raised since ``n_ev`` (each is one line, once per episode)."""
        new = sync.n_events - n_ev
        if new > 0:
            for ev in list(sync.events)[-min(new, len(sync.events)):]:
                self.ctx.logger.warning(f"input: {ev}")

    def _once_per_second(self, now: int, sync: InputStage) -> None:
        """Graph (wrong types), CPU, arrival rates."""
        self._next_graph_ns = now + 1_000_000_000
        self.check_graph()
        c = (time.process_time(), time.monotonic())
        if c[1] > self._cpu0[1]:
            self.stats.cpu_fraction = (c[0] - self._cpu0[0]) / (c[1] - self._cpu0[1])
        self._cpu0 = c
        sync.check_rates(now, self._clock_speed(now))

    def _clock_speed(self, now: int) -> float:
        """Speed of the node clock vs wall time over the rate window (1 without sim time; nan when the sim
        clock does not advance: the rate check is then skipped)."""
        if not self.settings.use_sim_time:
            return 1.0
        self._clock_pts.append((now, self.ctx.ros_now_s()))
        window_ns = self.core.configured_sync().rate_window_ns
        lo = now - window_ns
        while len(self._clock_pts) > 2 and self._clock_pts[1][0] <= lo:
            self._clock_pts.pop(0)
        (a0, r0), (a1, r1) = self._clock_pts[0], self._clock_pts[-1]
        if a1 - a0 < 0.5 * window_ns or r1 <= r0:
            return math.nan
        return (r1 - r0) / ((a1 - a0) * 1e-9)
