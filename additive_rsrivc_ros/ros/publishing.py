"""Outputs of a monitor channel: ``~/modes`` and ``/diagnostics``, published by their own thread.

A separate publisher thread publishes every report's estimate on ``~/modes`` and, with its data time and named
fields, on ``~/modes_stamped`` (``sensor_msgs/msg/PointCloud2``, :func:`.convert.modes_stamped`) (in order, once per
``1/publish_rate_hz`` cycle) and one ``/diagnostics`` array per ``diagnostics_period_s`` (1 s by default) from the
newest report, so publishing never holds up the consumption of the inputs (``~/modes`` messages are coalesced, and
counted, only past ``MODES_QUEUE``). ``/diagnostics`` holds one ``<node>: mode <i>`` status per mode with exactly the
interface's keys and one ``<node>: estimator`` status with counters, condition numbers, real-time factor, CPU, and the
delay from a sample's arrival to the return of the pipeline update that includes it; levels and messages are
composed by :mod:`..status` (ROS-free) and converted by :mod:`.convert`. ``<node>`` is the node name in the root
namespace and the full name without its leading '/' under a namespace (``axis1/additive_rsrivc_monitor``).
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray

from ..core.diagnosis.faults import Level
from ..core.monitor.pipeline import Report
from ..core.monitor.report_assembly import fault_fields
from ..outputs.status import Finding, StatusRecord, estimator_summary, mode_summary
from . import convert as cv
from .channel import MODES_QUEUE, ChannelContext, ChannelCore, ChannelSettings, ChannelStats, Outbox, RingStats
from .input_stage import InputStage

if TYPE_CHECKING:
    from rclpy.lifecycle import LifecyclePublisher

__all__ = ["DUPLICATE_NAME_CHECK_S", "MODES_QUEUE", "QUANTITIES", "Outputs", "Publisher", "RingStats",
           "alignment_values", "mode_message"]
QUANTITIES = ("natural_frequency", "damping", "gain")   # the fault flags' quantities in a mode's message


def alignment_values(al: Mapping[str, Any]) -> dict[str, Any]:
    """Estimator-status values of the stream aligner (controller invariant; core/input/alignment.py)."""
    if al.get("mode") != "invariant":
        return {"alignment": al.get("mode", "off")}
    return {"alignment": "verified" if al.get("verified") else "approximate",
            "alignment_offset_u_r": " ".join(str(v) for v in al.get("offset", [])),
            "alignment_realignments": int(al.get("realignments", 0)),
            "alignment_refilled": int(al.get("reconstructed", 0)),
            "alignment_set_aside": int(al.get("invalidated", 0)) + int(al.get("late", 0)),
            "alignment_relative_residual": float(al.get("relative_residual", math.nan))}


def mode_message(rep: Report, i: int) -> str:
    """``fault: natural_frequency down, ...`` for a mode with fault flags, ``blind: <why>`` for a mode whose tests
    are held (its decision state, core/diagnosis/decision.py), else the pipeline's phase."""
    faults = [f"{QUANTITIES[j]} {rep.directions[i][j]}".strip() for j in range(3) if rep.flags[i, j]]
    if faults:
        return "fault: " + ", ".join(faults)
    if i < len(rep.decisions) and rep.decisions[i].state.value == "blind" and rep.phase == "monitoring":
        return f"blind: {rep.decisions[i].reason}"
    return rep.phase


DUPLICATE_NAME_CHECK_S = 2.0
"""Seconds after activation at which the node looks for another node of its fully qualified name (DDS discovery
of a running graph takes a few hundred milliseconds on loopback)."""


@dataclass
class Outputs:
    """A channel's publishers (None until configured): ~/modes, ~/modes_stamped and /diagnostics."""

    modes: LifecyclePublisher | None = None           # Float64MultiArray
    modes_stamped: LifecyclePublisher | None = None   # PointCloud2
    diagnostics: LifecyclePublisher | None = None     # DiagnosticArray (shared by the joints of a group)


class Publisher:
    """The publisher thread and the composition of ``/diagnostics`` (a part of :class:`.channel_parts.ChannelParts`);
    ``extra_values`` adds values to the estimator status (a joint's CPU share)."""

    def __init__(self, ctx: ChannelContext, core: ChannelCore, settings: ChannelSettings, stats: ChannelStats,
                 outbox: Outbox, outputs: Outputs, extra_values: Callable[[], dict[str, Any]] | None = None) -> None:
        self.ctx = ctx
        self.core = core
        self.settings = settings
        self.stats = stats
        self.outbox = outbox
        self.outputs = outputs
        self.extra_values = extra_values
        self.reset()

    def reset(self) -> None:
        """The delay figures start afresh (a new configuration)."""
        self._delay_cache = (math.nan, math.nan, math.nan)
        self._delay_cache_ns = 0

    def run(self, stop: threading.Event, name_check: Callable[[], object]) -> None:
        """Publish the newest report on ~/modes once per ``1/publish_rate_hz`` and one /diagnostics array once
        per ``diagnostics_period_s``, each on its own schedule (no catch-up burst after falling behind);
        ``name_check`` once, ``DUPLICATE_NAME_CHECK_S`` after the start."""
        st = self.settings
        start = time.monotonic()
        due = {"modes": start + st.publish_period_s, "diagnostics": start + st.diag_period_s}
        name_check_s = start + DUPLICATE_NAME_CHECK_S     # once discovery has had time to see the graph
        while not stop.is_set():
            now = time.monotonic()
            if stop.wait(max(0.0, min(due.values()) - now)):
                break
            now = time.monotonic()
            if now >= name_check_s:
                name_check_s = math.inf
                name_check()
            for out, period in (("modes", st.publish_period_s), ("diagnostics", st.diag_period_s)):
                if now < due[out]:
                    continue
                due[out] = max(due[out] + period, now)   # fell behind (loaded CPU): no catch-up burst
                self.publish_guarded(out)

    def publish_guarded(self, out: str) -> None:
        """Publish ``out`` (modes | diagnostics); an exception is counted and logged once, never raised."""
        try:
            if out == "modes":
                self._publish_modes()
            else:
                self._publish_diagnostics()
        except Exception as exc:  # noqa: BLE001 - reported like a worker error
            stats = self.stats
            stats.errors += 1
            msg = f"publishing failed: {type(exc).__name__}: {exc}"
            if msg != stats.last_error:
                self.ctx.logger.error(msg)
            stats.last_error = msg

    def _current(self) -> tuple[Report | None, np.ndarray | None]:
        """(report, modal) for /diagnostics: the newest report (the same vetted estimate as the last ~/modes
        message), else, before any report (a state restored from ``state_file``), the live estimate when the worker
        lets go of the lock within 20 ms, else the last snapshot."""
        outbox, core = self.outbox, self.core
        rep = outbox.latest_report          # read once; the worker only ever replaces it (no lost update)
        if rep is not None:
            return rep, rep.modal
        if core.lock.acquire(timeout=0.02):
            try:
                if core.pipeline is not None:
                    outbox.snapshot = (core.pipeline.last_report, core.pipeline.modal())
                    outbox.restored = None if core.pipeline.last_report is not None else \
                        fault_fields(core.pipeline.faults)
            finally:
                core.lock.release()
        return outbox.snapshot

    def _publish_modes(self) -> None:
        """~/modes and ~/modes_stamped (the same estimate with its data time and named fields): every report's
        estimate not published yet, in order."""
        modes_pub, stamped_pub = self.outputs.modes, self.outputs.modes_stamped
        sync, outbox = self.core.sync, self.outbox
        if sync is None or modes_pub is None or not self.ctx.activity.active:
            return
        while outbox.modes_queue:
            t_s, modal = outbox.modes_queue.popleft()
            if sync.rate_error:       # estimates on a wrong time scale: none is published
                continue
            modes_pub.publish(cv.modes_array(modal))
            if stamped_pub is not None:
                stamped_pub.publish(cv.modes_stamped(modal, round(t_s * 1e9)))
            outbox.reports_published += 1

    def _publish_diagnostics(self) -> None:
        """/diagnostics: one status per mode and the estimator status, always (STALE without data)."""
        sync, diag_pub = self.core.sync, self.outputs.diagnostics
        if sync is None or diag_pub is None or not self.ctx.activity.active:
            return
        rep, modal = self._current()
        silent = sync.silent(time.monotonic_ns(), self.settings.stale_timeout_s, self.ctx.activity.looking_since_ns)
        hw = self.settings.hardware_id or self.ctx.name
        arr = DiagnosticArray()
        arr.header.stamp = self.ctx.clock.now().to_msg()
        arr.status = [cv.mode_status(r, hw) for r in self._mode_records(rep, modal, silent)]
        arr.status.append(cv.status(self._estimator_record(rep, silent), hw))
        diag_pub.publish(arr)

    def status_prefix(self) -> str:
        """Name prefix of this node's /diagnostics statuses: the node name in the root namespace (as ever), the
        full name without its leading '/' under a namespace (``axis1/additive_rsrivc_monitor``), so that the
        monitors of several axes publishing on the one /diagnostics topic never share a status name."""
        return self.ctx.name.lstrip("/")

    def _mode_records(self, rep: Report | None, modal: np.ndarray | None, silent: list[str]) -> list[StatusRecord]:
        """One ``<node>: mode <i>`` record per mode (none while the modes are being found)."""
        n_modes = self.core.configured_cfg().K if modal is None else len(modal)
        silent_text = "no data on " + ", ".join(self.core.topics[s] for s in silent) if silent else ""
        out = []
        rate_error = self.core.sync is not None and bool(self.core.sync.rate_error)
        for i in range(n_modes):
            if rate_error:               # estimates on a wrong time scale: no number; the estimator status says why
                out.append(StatusRecord(f"{self.status_prefix()}: mode {i + 1}", Level.ERROR,
                                        "no estimate published: loop_rate_hz disagrees with the data's timing",
                                        {f: math.nan for f in cv.MODE_FIELDS}))
                continue
            vals: dict[str, Any] = {f: math.nan for f in cv.MODE_FIELDS} if modal is None else \
                {f: float(modal[i, j]) for j, f in enumerate(cv.MODE_FIELDS)}
            found = None
            restored = self.outbox.restored if rep is None else None
            if restored is not None and len(restored["baseline"]) == n_modes:   # a restored state, no report yet
                vals.update({k: float(restored["baseline"][i, q]) for q, k in enumerate(cv.BASELINE_FIELDS)})
                vals.update({k: bool(restored["flags"][i, q]) for q, k in enumerate(cv.FLAG_FIELDS)})
            if rep is not None and rep.K == n_modes:
                md = rep.mode_dict(i)
                vals.update({k: md[k] for k in (*cv.BASELINE_FIELDS, *cv.FLAG_FIELDS)})
                if i < len(rep.decisions):      # the mode's decision state and why (core/diagnosis/decision.py)
                    vals.update(decision_state=rep.decisions[i].state.value, decision_reason=rep.decisions[i].reason)
                found = Finding(Level(int(rep.mode_levels[i])), mode_message(rep, i))
            level, msg = mode_summary(found, silent=silent_text, estimating=rep is not None and rep.estimating,
                                      looking=bool(self.ctx.activity.looking_since_ns))
            out.append(StatusRecord(f"{self.status_prefix()}: mode {i + 1}", level, msg, vals))
        return out

    def _delays(self) -> tuple[float, float, float]:
        """Median, p95, max of the delays; recomputed at most once a second (composition stays cheap)."""
        now = time.monotonic_ns()
        if now - self._delay_cache_ns > 1_000_000_000 or math.isnan(self._delay_cache[0]):
            v = self.stats.delays_ms.values().copy()
            if v.size:
                p50, p95, p100 = (float(x) for x in np.percentile(v, (50, 95, 100)))
                self._delay_cache = (p50, p95, p100)
            else:
                self._delay_cache = (math.nan, math.nan, math.nan)
            self._delay_cache_ns = now
        return self._delay_cache

    def _sync_values(self, sync: InputStage) -> dict[str, Any]:
        """Key/values of the input stage (counters, queues, arrival rates)."""
        sc = sync.counters
        return {
            "input_pauses": sc.gaps,
            "misaligned_events": sc.mismatches,
            "unmatched_messages": sc.unmatched,
            "malformed_messages": sum(self.stats.malformed.values()),
            "queue_backlog": max((len(q) + len(p) for q, p in zip(sync.queues, sync.pending, strict=True)),
                                 default=0),
            "queue_bound_samples": sync.max_queue,
            "queue_dropped": sum(sc.queue_dropped),
            "queue_dropped_per_topic": " ".join(f"{lb}={n}" for lb, n in zip(sync.labels, sc.queue_dropped,
                                                                            strict=True)),
            "arrival_rate_hz": " ".join(f"{lb}={cv.num(round(r, 1))}" for lb, r in zip(sync.labels,
                                                                                  sync.measured_rate, strict=True)),
            "rate_mismatches": sc.rate_mismatches,
        }

    def estimator_values(self, rep: Report | None, h: Mapping[str, Any], silent: list[str]) -> dict[str, Any]:
        """Key/values of the estimator status (counters, health, timing), in the published order."""
        sync, pipe = self.core.configured_sync(), self.core.configured_pipeline()
        stats, outbox = self.stats, self.outbox
        sc = sync.counters
        est = rep.estimator_health if rep is not None else None     # core/estimation/estimator.py EstimatorHealth
        cond = [c for c in (est.cond if est is not None else ()) if c is not None]
        rtf = stats.data_s / stats.busy_s if stats.busy_s > 0 else math.nan
        d50, d95, dmax = self._delays()
        return {
            "phase": rep.phase if rep is not None else pipe.phase,
            "samples_received": sum(sc.received),
            "samples_aligned": sc.aligned,
            "samples_processed": int(h.get("samples_processed", 0)),
            "samples_dropped": int(h.get("samples_dropped", 0)) + sc.dropped,
            "samples_skipped": int(h.get("samples_skipped", 0)),
            "nonfinite_samples": int(h.get("nonfinite", 0)),
            "out_of_order": int(h.get("out_of_order", 0)) + sc.out_of_order,
            "duplicate_stamps": int(h.get("duplicates", 0)),
            "gaps": int(h.get("gaps", 0)),
            **self._sync_values(sync),
            **alignment_values(h.get("alignment") or {}),
            "node_stalls": stats.node_stalls,
            "node_stall_max_s": float(stats.node_stall_max_s),
            "node_stall_gaps": sc.node_stall_gaps,
            "worker_stalls": stats.worker_stalls,
            "worker_stall_max_s": float(stats.worker_stall_max_s),
            "reports_coalesced": max(0, outbox.reports_made - outbox.reports_published),
            "projections": int(sum(est.projections)) if est is not None else 0,
            "reprimes": int(est.reprimes or 0) if est is not None else 0,
            "condition_number": float(max(cond)) if cond else math.nan,
            "condition_number_per_mode": " ".join(cv.num(c) for c in cond),
            "residual_variance": float(est.residual_var or math.nan) if est is not None else math.nan,
            "not_identifiable": ", ".join((h.get("joint_check") or {}).get("not_identifiable") or []),
            "initializations": int(h.get("initializations", 0)),
            "reinitializations": int(h.get("reinitializations", 0)),
            "real_time_factor": float(rtf),
            "cpu_fraction": float(stats.cpu_fraction),
            "delay_median_ms": d50,
            "delay_p95_ms": d95,
            "delay_max_ms": dmax,
            "internal_errors": stats.errors,
            "silent_topics": " ".join(self.core.topics[s] for s in silent),
            "wrong_types": "; ".join(stats.wrong_types),
            **sync.extra_values(),
            **(self.extra_values() if self.extra_values is not None else {}),
        }

    def _input_reasons(self, sync: InputStage) -> list[str]:
        """Open input problems that last (rate mismatch, queue overflow, a busy estimator): WARN reasons."""
        out = [sync.rate_reason(lb, r, sync.expected_rate) for lb, r in list(sync.rate_mismatch.items())]
        out += sync.lasting_reasons()
        out += sync.queue_reasons()
        busy = self.stats.push_started_ns
        if busy and time.monotonic_ns() - busy > 500_000_000:
            out.append(f"estimator busy for {(time.monotonic_ns() - busy) * 1e-9:.1f} s (the node, not the "
                       "inputs: samples wait in the queues)")
        return out

    def _estimator_record(self, rep: Report | None, silent: list[str]) -> StatusRecord:
        """The ``<node>: estimator`` record: values, and level and reasons composed by :func:`estimator_summary`."""
        sync, stats = self.core.configured_sync(), self.stats
        h = dict(rep.health) if rep is not None else {}
        h.update(self.core.configured_pipeline().counters.to_dict())      # live counters (the report may be older)
        vals = self.estimator_values(rep, h, silent)
        lasting = self._input_reasons(sync)
        recent = time.monotonic_ns() - sync.last_event_ns < 5e9 and sync.last_event_ns > 0
        event = None
        if recent:     # the newest input event of the last 5 s (its text once: not when it is a lasting reason)
            event = Finding(Level.WARN, sync.events[-1] if sync.events and sync.events[-1] not in lasting else None)
        level, text = estimator_summary(
            Finding(Level(int(h.get("level", 0))) if rep is not None else Level.STALE),
            list(h.get("reasons", [])), recent_event=event, lasting=lasting,
            internal_error=stats.last_error if stats.errors else "",
            silent="no data on " + ", ".join(f"{self.core.topics[s]} for more than "
                                             f"{self.settings.stale_timeout_s:g} s" for s in silent) if silent else "",
            wrong_types="wrong message type: " + "; ".join(stats.wrong_types) if stats.wrong_types else "")
        if sync.rate_error:         # the configured time scale contradicts the data: an error, nothing published
            level, text = Level.ERROR, "; ".join(t for t in (sync.rate_error, text) if t)
        vals["reasons"] = text
        msg = text or (vals["phase"] if rep is not None else "no data")
        return StatusRecord(f"{self.status_prefix()}: estimator", level, msg, vals)
