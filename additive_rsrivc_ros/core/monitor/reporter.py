"""The monitor pipeline's reports at ``publish_rate_hz``: the health status, the fault decision on the estimate and
the :class:`.report_record.Report` they make (its health keys: :mod:`.report_assembly`).

At each due instant the current model is checked (finite, stabilized by ``C_d``), the health monitor assesses the
estimate or says what the start is doing, and the fault tests (:mod:`.faults`), the joint check and each mode's
decision state (:mod:`.decision`) go into the report with the events and notices since the last one.
"""

from __future__ import annotations

import math
from typing import Any, Protocol

import numpy as np

from ..diagnosis.faults import FaultEvent, FaultMonitor, FaultSettings, HealthMonitor, HealthStatus, Level
from ..diagnosis.joint_check import JointChecker
from ..estimation.estimator import EstimatorHealth, MonitorSettings, RecursiveEstimator
from ..identification.adequacy import ModelOrderCheck
from ..identification.autostart import ModeSearch
from ..input.alignment import InvariantAligner
from ..input.input_screen import InputScreen
from . import report_assembly
from .model_start import ModelStart
from .report_assembly import AlignmentNotes, BlindTime
from .report_record import Counters, Report


class ReportHost(Protocol):
    """What the reporter reads on the pipeline it serves (:class:`.pipeline.MonitorPipeline`): its current modes,
    monitors and model state. The reporter sets none of them; the start (:class:`.model_start.ModelStart`) does."""

    cfg: MonitorSettings
    K: int
    settings: FaultSettings
    health: HealthMonitor
    search: ModeSearch | None
    faults: FaultMonitor | None
    initialized: bool
    no_model: str | None
    model_max_pole: float
    marked_gaps: int

    @property
    def finding_modes(self) -> bool: ...

    @property
    def phase(self) -> str: ...

    @property
    def estimator(self) -> RecursiveEstimator: ...

    @property
    def fault_monitor(self) -> FaultMonitor: ...

    @property
    def joint_checker(self) -> JointChecker: ...

    @property
    def mode_search(self) -> ModeSearch: ...

    def modal(self) -> np.ndarray: ...

    def apply_memory(self) -> None: ...


class Reporter:
    """One run's reports: when the next is due, what the last said, and the events, notices and report-window counts
    gathered since (see the module docstring)."""

    def __init__(self, host: ReportHost, *, counters: Counters, screen: InputScreen, start: ModelStart,
                 order_check: ModelOrderCheck, aligner: InvariantAligner | None,
                 alignment_notes: AlignmentNotes) -> None:
        self.host = host
        self.counters = counters
        self.screen = screen
        self.start = start
        self.order_check = order_check
        self.aligner = aligner
        self.alignment_notes = alignment_notes
        self.blind_time = BlindTime()
        self.next_publish = 0.0               # time (since t0) of the next report
        self.window_n = 0                     # samples / repeated outputs since the last report
        self.window_repeated = 0
        self.pending_opened: list[FaultEvent] = []
        self.pending_closed: list[FaultEvent] = []
        self.notices: list[str] = []
        self.last_report: Report | None = None

    def report(self, reports: list[Report], t_now: float, period: float) -> None:
        """One report at the latest due instant ``<= t_now`` (s since the first sample), every ``period`` s."""
        h = self.host
        t_rep = self.next_publish
        if t_now >= t_rep + period:      # a gap swallowed several instants: report only the latest
            t_rep = t_rep + math.floor((t_now - t_rep) / period) * period
        self.next_publish = t_rep + period
        s = h.settings
        if self.window_n > 0 and self.window_repeated > s.health_max_repeated_fraction * self.window_n:
            h.health.note("repeated_output", t_rep, f"output repeats its previous value in {self.window_repeated} "
                          f"of {self.window_n} samples (dropped or held sensor samples)")
        self.window_n = self.window_repeated = 0
        modal = h.modal()
        if h.initialized and h.cfg.closed_loop:    # every report (~0.25 ms for K = 2, delay 4)
            problem = self.start.model_problem("current model", modal)
            if problem is not None:
                self.counters.invalid_models += 1
                self.counters.reinitializations += 1
                self.start.no_valid_model(t_rep, problem)
                modal = h.modal()        # NaN: no model
        est_health = h.estimator.health if h.initialized else None
        status = self._health_status(t_rep, modal, est_health)
        if h.initialized:
            self._decide(t_rep, modal, status)
        health = self._health_dict(status, est_health, t_rep)
        decisions = report_assembly.decisions(h.faults, status, h.initialized, h.K, h.no_model)
        health["modes"] = [d.to_dict() for d in decisions]
        self.order_check.apply(health, Level.WARN)
        health.update(self.counters.to_dict())
        health["estimator"] = {} if est_health is None else est_health.to_dict()
        health["stuck"] = self.screen.stuck
        health["baseline_source"] = None if h.faults is None or h.faults.baseline is None else \
            h.faults.baseline.source
        if self.screen.spacing.error:           # the model's time scale contradicts the stamps: no number
            modal = np.full_like(modal, np.nan)
        health["time_scale"] = self.screen.spacing.error or None
        rep = Report(time_s=t_rep, modal=modal, **report_assembly.fault_fields(h.faults),
                     events_opened=self.pending_opened, events_closed=self.pending_closed, health=health,
                     phase=h.phase, estimating=h.initialized, notices=self.notices, estimator_health=est_health,
                     decisions=decisions)
        reports.append(rep)
        self.last_report = rep
        self.pending_opened, self.pending_closed, self.notices = [], [], []
        if h.initialized and "divergence" in status.values.get("new_issues", []):
            self.start.reinitialize(t_rep)

    def _health_status(self, t_rep: float, modal: np.ndarray, est_health: EstimatorHealth | None) -> HealthStatus:
        """The health monitor's status at this report: assessed on the estimate, or what the start is doing."""
        h = self.host
        if est_health is not None:
            if est_health.hold_remaining > 0:
                auto = est_health.reprimes > h.marked_gaps
                h.health.note("repriming", t_rep, "estimator filters re-priming after non-finite filter states"
                              if auto else "estimator filters re-priming after a data break")
            return h.health.assess(t_rep, modal, est_health)
        if h.finding_modes:
            h.health.note("initializing", t_rep, h.mode_search.status_line())
            status = h.health.status(t_rep)
            if set(status.values["issues"]) <= {"initializing"}:
                status.level = Level.STALE    # no model yet, nothing wrong: as a status without data
            return status
        if h.no_model is not None:
            h.health.note("no_valid_model", t_rep, h.no_model)
        h.health.note("initializing", t_rep, f"initializing: collecting {h.cfg.init_duration_s:g} s of "
                      "valid data for the offline initialization")
        return h.health.status(t_rep)

    def _decide(self, t_rep: float, modal: np.ndarray, status: HealthStatus) -> None:
        """The fault tests and the joint check on this report's estimate; the estimator's memory follows them."""
        h = self.host
        upd = h.fault_monitor.update(t_rep, modal, hold=status.hold,
                                     suspect_since=status.values.get("advisory_since"),
                                     mode_hold=status.mode_hold(h.K), model_flagged=self.order_check.flagged)
        self.pending_opened += upd.opened
        self.pending_closed += upd.closed
        h.apply_memory()
        joint = None if status.hold else h.joint_checker.step(t_rep, h.faults)
        if joint is not None:
            self.pending_opened += joint.opened
            self.pending_closed += joint.closed

    def _health_dict(self, status: HealthStatus, est_health: EstimatorHealth | None, t_rep: float) -> dict[str, Any]:
        """The report's health (docs/INTERFACE.md): the status, then what the start, the aligner and the fault
        monitor add (:mod:`.report_assembly`)."""
        h = self.host
        health = status.to_dict()
        if h.search is not None:
            health["autostart"] = h.search.info()
        report_assembly.anomaly_reason(health, h.faults, h.K, t_rep)
        self.alignment_notes.to_health(health, self.aligner, t_rep)
        health["anomaly_since"] = None if h.faults is None else h.faults.anomaly_since
        health["model_valid"] = h.initialized
        health["no_model_reason"] = None if h.initialized else (
            "finding modes (no guesses)" if h.finding_modes else (h.no_model or "not initialized yet"))
        health["closed_loop_max_pole"] = h.model_max_pole if h.initialized else math.nan
        if h.faults is None:
            health["blind_since"], health["baseline_trusted"], health["baseline_note"] = None, False, ""
            return health
        self.blind_time.to_health(health, h.faults, h.initialized, status.hold, t_rep)
        report_assembly.identifiability_health(health, h.faults, h.cfg.structures)
        report_assembly.baseline_health(health, h.faults)
        return health
