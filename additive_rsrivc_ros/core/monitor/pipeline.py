"""MonitorPipeline: sample validation, recursive additive SRIVC and the fault decision (ROS-free).

The one object the node, ``rsrivc_diagnose`` and ``rsrivc_fleet`` drive: 0. **Alignment** (closed loop):
   :class:`.alignment.InvariantAligner` checks ``u = C_d(q)(r - y)`` and re-pairs streams that lost or repeated a
   message before the estimator sees them.
1. **Screening** (:mod:`.input_screen`): bad stamps dropped; non-finite, absurd and repeated outputs kept on the
   grid as invalid samples; short gaps filled, long ones and stuck sensors re-prime the filters.
1b. **Automatic start** without guesses (:mod:`.autostart`): reports have K = 0 until modes are found.
2. **Start** (:mod:`.model_start`): initialization on ``init_duration_s`` ([A-SRIVC] eq. 29), then recursion; a
   model is published only if it is finite and ``C_d`` stabilizes it (checked at every report), else NaN.
3. **Diagnosis** at ``publish_rate_hz`` (:mod:`.reporter`): health, baseline and tests (:mod:`.faults`), each
   mode's decision state (:mod:`.decision`) in a :class:`.report_record.Report` (health: :mod:`.report_assembly`).
Runtime changes are checked by :mod:`.param_changes`, saved states by :mod:`.pipeline_state`. Reports give
``time_s`` since the first sample ever pushed (kept across :meth:`get_state`/:meth:`set_state`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from ..diagnosis.faults import FaultEvent, FaultMonitor, FaultSettings, HealthMonitor
from ..diagnosis.joint_check import JointChecker
from ..estimation.estimator import MonitorSettings, RecursiveEstimator
from ..identification.adequacy import ModelOrderCheck
from ..identification.autostart import ModeSearch
from ..input.alignment import AlignedBlock, InvariantAligner
from ..input.input_screen import ABSOLUTE_BOUND, InputScreen, MagnitudeGuard, Screened
from ..params import DEFAULT_MEMORY_S
from . import param_changes
from .model_start import ModelStart
from .pipeline_state import STATE_VERSION, restore_target, state_record
from .report_assembly import AlignmentNotes
from .report_record import Counters, PipelineError, Report
from .reporter import Reporter

FLOAT64_TYPE = "std_msgs/msg/Float64"
__all__ = ["ABSOLUTE_BOUND", "STATE_VERSION", "Counters", "MagnitudeGuard", "MonitorPipeline", "PipelineError",
           "Report"]


EstimatorFactory = Callable[[MonitorSettings], RecursiveEstimator]
"""Builds the estimator for a configuration's modes (default :meth:`.recursive.RecursiveAdditiveSRIVC.from_config`)."""


def _default_factory(cfg: MonitorSettings) -> RecursiveEstimator:
    from ..estimation.recursive import RecursiveAdditiveSRIVC
    return RecursiveAdditiveSRIVC.from_config(cfg)


class MonitorPipeline:
    """Validation + :class:`RecursiveAdditiveSRIVC` + fault logic; see the module docstring.

    ``push(t, r, u, y)`` accepts any number of samples and returns the reports that fell due. Mode
    numbering in events is 1-based (the status name ``mode <i>``).
    """

    def __init__(self, cfg: MonitorSettings, *, state: Mapping[str, Any] | None = None,
                 estimator_factory: EstimatorFactory | None = None) -> None:
        self.cfg_given = cfg                  # as configured (no guesses: the modes are found from the data)
        self.cfg = cfg                        # with the modes the estimator uses (found ones after an automatic start)
        self.rate = float(cfg.loop_rate_hz)
        self.h = 1.0 / self.rate
        self._factory = estimator_factory or _default_factory
        self.settings = FaultSettings.from_params(cfg.params)
        self.settings.check(cfg.K or cfg.mode_count or None)
        if cfg.auto_modes and self.settings.has_given_baseline and not cfg.mode_count:
            raise PipelineError("faults.baseline.* is given but the modes are to be found from the data with "
                                "modes.count 0: give the mode guesses, or modes.count")
        self.publish_period = 1.0 / float(cfg.publish_rate_hz)
        self.init_samples = max(2, int(round(float(cfg.init_duration_s) * self.rate)))
        self._fault_changes: dict[str, Any] = {}   # runtime faults.* changes (kept across reset)
        self._new_run()
        if state is not None:
            self.set_state(state)

    # ------------------------------------------------------------------------------------------- lifecycle
    def new_estimator(self) -> RecursiveEstimator:
        """A fresh estimator for the current modes, with the configured memories."""
        est = self._factory(self.cfg)
        est.set_memory(self.memory_s)
        self._est_memory = self.memory_s.copy()
        return est

    def _wanted_memory(self, faults: FaultMonitor) -> np.ndarray:
        """The estimator's memories: the configured ones, shortened while the fault monitor tracks a detected change
        of a mode (S7, variable forgetting; never below 50 samples)."""
        return np.minimum(self.memory_s, np.maximum(self.memory_s * faults.memory_scale(), 50.0 / self.rate))

    def apply_memory(self) -> None:
        """Give the estimator :meth:`_wanted_memory` when it changed (applied here only)."""
        if self.est is None or self.faults is None:
            return
        mem = self._wanted_memory(self.faults)
        if not np.array_equal(mem, self._est_memory):
            self.est.set_memory(mem)
            self._est_memory = mem

    @property
    def finding_modes(self) -> bool:
        """No guesses and the automatic start has not found the modes yet (K = 0, nothing is estimated)."""
        return self.search is not None and self.search.found is None

    # typed access to the parts that exist once the modes are known (a call before is a programming error)
    @property
    def estimator(self) -> RecursiveEstimator:
        if self.est is None:
            raise PipelineError("no estimator: the modes are not known yet")
        return self.est

    @property
    def fault_monitor(self) -> FaultMonitor:
        if self.faults is None:
            raise PipelineError("no fault monitor: the modes are not known yet")
        return self.faults

    @property
    def joint_checker(self) -> JointChecker:
        if self.joint is None:
            raise PipelineError("no joint check: the modes are not known yet")
        return self.joint

    @property
    def mode_search(self) -> ModeSearch:
        if self.search is None:
            raise PipelineError("no mode search: the modes were given")
        return self.search

    @property
    def stream_aligner(self) -> InvariantAligner:
        if self.aligner is None:
            raise PipelineError("no stream aligner configured")
        return self.aligner

    def _set_modes(self, cfg: MonitorSettings) -> None:
        """Estimator, fault and health monitors for the modes of ``cfg`` (none while the modes are searched)."""
        self.cfg = cfg
        self.K = cfg.K
        self.memory_s = np.array([m.memory_s for m in cfg.modes], dtype=float)
        if self.K == 0:                       # automatic start pending: a health monitor for the notes only
            mem = list(cfg.mode_memories_s) or [DEFAULT_MEMORY_S]
            self.est, self.faults, self.joint = None, None, None
            self.health = HealthMonitor([max(mem)], self.settings, rate_hz=self.rate)
            return
        self.settings.check(self.K)
        self.est = self.new_estimator()
        self.faults = FaultMonitor(self.memory_s, self.settings, structures=cfg.structures)
        self.joint = JointChecker(cfg)
        self.health = HealthMonitor(self.memory_s, self.settings, structures=cfg.structures, rate_hz=self.rate)

    def switch_modes(self, cfg: MonitorSettings, closed: tuple[str, ...] = ()) -> None:
        """:meth:`_set_modes` for new modes in the middle of a run: the health notes so far are kept (except the
        ``closed`` kinds), and their counts."""
        old = self.health
        self._set_modes(cfg)
        for kind, (t_seen, msg) in old.active.items():
            if kind not in closed:
                self.health.note(kind, t_seen, msg, count=0)
        self.health.counts.update(old.counts)

    def _new_run(self) -> None:
        self.search = ModeSearch(self.cfg_given) if self.cfg_given.auto_modes else None
        self._set_modes(self.cfg_given)
        self.counters = Counters()
        self.screen = InputScreen(self.rate, self.counters)    # stamps, values, gaps, stuck sensor
        self.start = ModelStart(self, self.init_samples)       # initialization and starts from the data
        self.initialized = False
        self.aligner = _make_aligner(self.cfg)
        self.alignment_notes = AlignmentNotes()
        self.no_model: str | None = None      # why there is no valid model (None: valid, or not tried yet)
        self.model_max_pole = math.nan        # closed-loop spectral radius of the current model with C_d
        self.marked_gaps = 0                  # re-primes the pipeline asked for (others: non-finite filter states)
        opts = self.cfg_given.estimator
        self.order_check = ModelOrderCheck(self.rate, opts.order_check_memory_lengths, opts.order_check_relevance)
        self.reporter = Reporter(self, counters=self.counters, screen=self.screen, start=self.start,
                                 order_check=self.order_check, aligner=self.aligner,
                                 alignment_notes=self.alignment_notes)

    def reset(self) -> None:
        """Start over: new estimator (initialized from the next data), no baseline, counters zeroed; without
        guesses the modes are found again on the next data."""
        self._new_run()

    def rebaseline(self) -> list[FaultEvent]:
        """Learn a new baseline from the next healthy window; open events are closed now (and returned)."""
        if self.faults is None:               # modes not found yet: the baseline is learned after the start anyway
            return []
        t = self.rel(self.t_last) if self.t_last is not None else 0.0
        closed = self.faults.rebaseline(t)
        self.reporter.pending_closed += closed
        return closed

    @property
    def notices(self) -> list[str]:
        """One-line news for the next report (:attr:`.report_record.Report.notices`)."""
        return self.reporter.notices

    @property
    def last_report(self) -> Report | None:
        """The latest report of this run (None before it)."""
        return self.reporter.last_report

    @property
    def phase(self) -> str:
        if self.finding_modes:
            return "finding modes"
        return "initializing" if not self.initialized else self.fault_monitor.phase

    # ------------------------------------------------------------------------------------------- runtime params
    def update_params(self, params: Mapping[str, Any]) -> None:
        """Apply runtime-changeable parameters: ``modes.memory_s``, ``publish_rate_hz``, ``faults.*``
        (:mod:`.param_changes`). Raises :class:`PipelineError` (nothing changed) on a bad value.
        """
        fp = {k: v for k, v in params.items() if k.startswith("faults.")}
        if fp:
            self.settings = param_changes.fault_settings(fp, self.faults, self.cfg_given, self._fault_changes)
            self._fault_changes.update(fp)
            self.health.settings = self.settings
        if "modes.memory_s" in params and self.K == 0:
            self.cfg_given = self.cfg_given.with_memory(param_changes.given_memories(params["modes.memory_s"],
                                                                                     self.rate))
            if self.search is not None:
                self.search.cfg = self.cfg_given
        elif "modes.memory_s" in params:
            mem = param_changes.mode_memories(params["modes.memory_s"], self.K, self.rate)
            self.memory_s = mem
            self.fault_monitor.set_memory(mem)
            self.health.memory_s = mem
            self._est_memory = np.full(self.K, math.nan)
            self.apply_memory()
        if "publish_rate_hz" in params:
            self.publish_period = param_changes.publish_period(params["publish_rate_hz"])

    # ------------------------------------------------------------------------------------------- data path
    @property
    def t0(self) -> float | None:
        """Absolute time of the first sample (the origin of every report time); None before it."""
        return self.screen.t0

    @t0.setter
    def t0(self, value: float | None) -> None:
        self.screen.t0 = value

    @property
    def t_last(self) -> float | None:
        """Absolute time of the last accepted sample."""
        return self.screen.t_last

    def rel(self, t_abs: float) -> float:
        """Seconds since the first sample (0 before it)."""
        return self.screen.rel(t_abs)

    def push(self, t: np.ndarray, r: np.ndarray | None, u: np.ndarray, y: np.ndarray) -> list[Report]:
        """Validate, estimate and diagnose a batch of samples; return the reports that fell due.

        ``t`` in seconds (any fixed origin), ``r`` may be None in open loop; 1-D arrays of equal length.
        """
        t = np.atleast_1d(np.asarray(t, dtype=float))
        u = np.atleast_1d(np.asarray(u, dtype=float))
        y = np.atleast_1d(np.asarray(y, dtype=float))
        r = np.zeros_like(u) if r is None else np.atleast_1d(np.asarray(r, dtype=float))
        if not (t.ndim == r.ndim == u.ndim == y.ndim == 1 and t.size == r.size == u.size == y.size):
            raise PipelineError(f"t, r, u, y must be 1-D of equal length, got sizes {t.size}, {r.size}, {u.size}, "
                                f"{y.size}")
        if t.size == 0:
            return []
        self.counters.samples_in += t.size
        t, r, u, y = self.screen.accept_stamps(t, r, u, y, self.health)
        if t.size == 0:
            return []
        if self.aligner is None:
            return self._ingest(t, r, u, y)
        return self._ingest_aligned(self.aligner.push(t, r, u, y))

    def flush(self) -> list[Report]:
        """End of a record: release the samples the stream aligner still holds back (``alignment.lag_s``)."""
        if self.aligner is None:
            return []
        return self._ingest_aligned(self.aligner.flush())

    def _ingest_aligned(self, blk: AlignedBlock) -> list[Report]:
        """Samples released by the aligner: its findings become health notes, then the usual validation."""
        n_late = self.alignment_notes.absorb(self.stream_aligner.stats)
        if n_late:
            # a shift found after misaligned samples reached the estimator: their filter states are wrong
            t_abs = float(blk.t[0]) if blk.n else (self.t_last or 0.0)
            self.health.note("misaligned", self.rel(t_abs), f"{n_late} samples reached the estimator misaligned "
                             "before the shift was detected (estimator re-primed)")
            if self.initialized:
                self.estimator.mark_gap()
        if blk.n == 0:
            return []
        assert blk.r is not None            # the stream aligner runs in closed loop only (it needs r)
        return self._ingest(blk.t, blk.r, blk.u, blk.y, aligner_invalid=blk.invalid)

    def _ingest(self, ta: np.ndarray, ra: np.ndarray, ua: np.ndarray, ya: np.ndarray,
                aligner_invalid: np.ndarray | None = None) -> list[Report]:
        """Screening (values, gaps, stuck sensor: :class:`.input_screen.InputScreen`), estimation and reports on
        stamp-checked samples, block by block between gaps and stuck transitions."""
        reports: list[Report] = []
        c, screen = self.counters, self.screen
        scr = screen.screen(ta, ra, ua, ya, aligner_invalid=aligner_invalid, settings=self.settings,
                            closed_loop=bool(self.cfg.closed_loop), fill_max=self._fill_max_samples,
                            health=self.health)
        for a, b in scr.blocks(screen.stuck):
            if scr.gap[a]:
                c.gaps += 1
                self._on_break(f"data gap of {scr.t[a] - scr.prev_t[a]:.4g} s", "data_gap", float(scr.t[a]))
            if scr.stuck[a]:
                if not screen.stuck:
                    c.stuck_episodes += 1
                    screen.stuck = True
                c.samples_dropped += b - a
                self.health.note("stuck_sensor", self.rel(float(scr.t[b - 1])), "stuck sensor: output constant at "
                                 f"{screen.last_y:.6g} since t={self.rel(float(scr.run_t0[a])):.3f} s; samples "
                                 "withheld")
                self._advance(scr, a, b, feed=False, reports=reports)
                continue
            if screen.stuck:
                screen.stuck = False
                self._on_break("sensor recovered", None, float(scr.t[a]))
            c.repeated += int(scr.repeated[a:b].sum())
            self._advance(scr, a, b, feed=True, reports=reports)
        screen.t_last = float(scr.t[-1])
        return reports

    def _fill_max_samples(self) -> int:
        """Longest gap (missing samples) filled with invalid samples instead of a re-prime: 5 % of the shortest
        period of the modelled modes (the held input then barely moves the filter states), at least one sample."""
        f = self.modal()[:, 0] if self.initialized else np.array(
            [m.natural_frequency_hz for m in self.cfg.modes if m.natural_frequency_hz], float)
        f = f[np.isfinite(f) & (f > 0)] if f.size else f
        if f.size == 0:
            return 1
        return max(1, int(math.floor(0.05 * self.rate / float(f.max()))))

    def _on_break(self, why: str, kind: str | None, t_abs: float) -> None:
        """The sample grid is broken: re-prime the estimator ([RA-SRIVC] Algorithm 2 step 1) or restart the init
        buffer."""
        if kind is not None:
            self.health.note(kind, self.rel(t_abs), f"{why} (estimator re-primed)")
        if self.initialized:
            self.estimator.mark_gap()
            self.marked_gaps += 1
            self.joint_checker.recent.clear()
        else:
            self.start.clear_buffer()
            if self.joint is not None:       # held from before a re-initialization: not contiguous any more
                self.joint.recent.clear()
            if self.finding_modes:           # the search needs contiguous data too: its window starts again
                self.mode_search.clear()

    def _advance(self, scr: Screened, a: int, b: int, *, feed: bool, reports: list[Report]) -> None:
        """Feed samples ``[a, b)`` (or only pass their time when ``feed`` is False), reporting on the way.

        A report at instant T is made once every accepted sample before T was processed; instants that
        fall inside a gap are collapsed into one report.
        """
        assert self.t0 is not None          # set by the first accepted sample, before any is advanced
        while a < b:
            t_next = self.t0 + self.reporter.next_publish
            j = a + int(np.searchsorted(scr.t[a:b], t_next, side="left"))
            if feed and not self.initialized:
                j = min(j, a + (self.mode_search.need() if self.finding_modes else self.start.missing()))
            if j > a:
                if feed:
                    self._consume(scr.r[a:j], scr.u[a:j], scr.y[a:j], scr.valid[a:j], float(scr.t[j - 1]))
                    # counted in the report window they belong to
                    self.reporter.window_repeated += int(scr.repeated[a:j].sum())
                a = j
                continue
            self.reporter.report(reports, self.rel(float(scr.t[a])), self.publish_period)

    def _consume(self, r: np.ndarray, u: np.ndarray, y: np.ndarray, valid: np.ndarray, t_end: float) -> None:
        c = self.counters
        n = u.size
        c.samples_processed += n
        c.samples_skipped += int((~valid).sum())
        self.reporter.window_n += n
        if self.finding_modes:
            self.start.search_modes(r, u, y, valid, t_end)
        else:
            self.feed(r, u, y, valid, t_end)

    def feed(self, r: np.ndarray, u: np.ndarray, y: np.ndarray, valid: np.ndarray, t_end: float) -> None:
        """Samples to the estimator: the first ``init_duration_s`` to the offline initialization, then updates."""
        a, n = 0, u.size
        while a < n:
            if self.initialized:
                self.estimator.update(r[a:], u[a:], y[a:], valid[a:])
                self.joint_checker.add(r[a:], u[a:], np.where(valid[a:], y[a:], np.nan),
                                       float(self.fault_monitor.memory_s.max()))
                self.start.check_order(r[a:], u[a:], y[a:], valid[a:], t_end)
                return
            a += self.start.add(r[a:], u[a:], y[a:], valid[a:], t_end)

    # ------------------------------------------------------------------------------------------- reports
    def modal(self) -> np.ndarray:
        """Current (K, 6) estimate ``f_hz, zeta, gain`` and their std; NaN before the first initialization."""
        if not self.initialized:     # no valid model (before the first accepted initialization, or after one
            return np.full((self.K, 6), np.nan)   # was rejected / diverged): NaN, never the guesses
        return np.asarray(self.estimator.modal(), dtype=float).reshape(self.K, 6)

    # ------------------------------------------------------------------------------------------- state
    def get_state(self) -> dict[str, Any]:
        """Estimator, baseline, fault tests, health and clock as JSON-serializable data (:mod:`.pipeline_state`).

        A partially filled initialization buffer (or search window) is not saved (initialization restarts on new
        data); a restored running estimator re-primes on the first samples (they follow a gap). Modes found by the
        automatic start are saved (``found_modes``) and restored into a pipeline configured without guesses.
        """
        return state_record(cfg=self.cfg, rate=self.rate, estimator=self.estimator if self.initialized else None,
                            found=self.search.found if self.search is not None else None, faults=self.faults,
                            health=self.health, screen=self.screen, next_publish=self.reporter.next_publish,
                            counters=self.counters, memory_s=self.memory_s, aligner=self.aligner,
                            no_model=self.no_model)

    def set_state(self, state: Mapping[str, Any]) -> None:
        """Restore :meth:`get_state` output (same K, rate, controller, input delay, loop and mode structures);
        raises :class:`PipelineError` with a one-line reason otherwise (never a silent restore)."""
        try:
            found, target = restore_target(state, self.cfg_given, self.rate)
            p = state["pipeline"]
            self._new_run()
            if target is not self.cfg_given:
                self.mode_search.found = found
                self._set_modes(target)
            mem = np.asarray(p["memory_s"], dtype=float)
            if mem.shape == (self.K,) and not np.array_equal(mem, self.memory_s):
                self.update_params({"modes.memory_s": mem.tolist()})
            if state["estimator"] is not None:
                self.estimator.set_state({k: np.asarray(v) for k, v in state["estimator"].items()})
                self.initialized = True
                self.marked_gaps = self.estimator.health.reprimes
            if self.faults is not None:
                self.faults.set_state(state["faults"])
                # the estimator's saved forgetting already holds a shortened memory (S7): only record it
                self._est_memory = self._wanted_memory(self.faults)
            self.health.set_state(state["health"])
            self.reporter.next_publish = float(p["next_publish"])
            vars(self.counters).update(vars(Counters(**p["counters"])))    # the screen counts into the same object
            self.screen.set_state(p)
            if self.aligner is not None and p.get("aligner") is not None:
                self.aligner.set_state(p["aligner"])
            self.no_model = None if self.initialized else p.get("no_model")
        except PipelineError:
            raise
        except (KeyError, TypeError, ValueError) as exc:
            raise PipelineError(f"saved state is incomplete or corrupt ({type(exc).__name__}: {exc})") from None


def _make_aligner(cfg: MonitorSettings) -> InvariantAligner | None:
    """The controller-invariant aligner when it applies (closed loop, Float64 signals, ``alignment.mode: auto``)."""
    opts = cfg.alignment
    if opts.mode == "off" or not cfg.closed_loop or cfg.controller is None:
        return None
    if any(sc.type != FLOAT64_TYPE for sc in cfg.signals.values()):
        return None   # stamped inputs (JointState) are paired exactly by their header stamps
    return InvariantAligner(cfg.controller, float(cfg.loop_rate_hz), **opts.aligner_options(float(cfg.loop_rate_hz)))
