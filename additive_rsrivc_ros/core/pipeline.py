"""MonitorPipeline: sample validation, recursive additive SRIVC and the fault decision (ROS-free).

The one object the node, ``rsrivc_diagnose`` and ``rsrivc_fleet`` drive: 0. **Alignment** (closed loop):
   :class:`.alignment.InvariantAligner` checks ``u = C_d(q)(r - y)`` and re-pairs streams that lost or repeated a
   message before the estimator sees them.
1. **Validation**: bad stamps dropped; non-finite, absurd (:class:`MagnitudeGuard`) and repeated outputs kept on the
   grid as invalid samples; short gaps filled, long ones and stuck sensors re-prime the filters
   ([RA-SRIVC] Algorithm 2 step 1). Garbage never reaches the estimator as data.
1b. **Automatic start** without guesses (:mod:`.autostart`): reports have K = 0 until modes are found.
2. **Initialization** on ``init_duration_s`` ([A-SRIVC] eq. 29), then recursion; a model is published only if it is
   finite and ``C_d`` stabilizes it (checked at every report), else NaN with the reason on health.
3. **Diagnosis** at ``publish_rate_hz``: health, baseline and tests (:mod:`.faults`), each mode's decision state
   (:mod:`.decision`) in a :class:`Report`.
Reports give ``time_s`` since the first sample ever pushed (kept across :meth:`get_state`/:meth:`set_state`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .adequacy import ModelOrderCheck
from .alignment import AlignedBlock, InvariantAligner
from .autostart import FoundModes, ModeSearch
from .decision import Hold, ModeDecision, decide
from .estimator import EstimatorHealth, MonitorSettings, RecursiveEstimator
from .faults import FaultEvent, FaultMonitor, FaultSettings, HealthMonitor, HealthStatus, Level
from .joint_check import JointChecker, applicable_mask
from .params import DEFAULT_MEMORY_S
from .time_scale import StampSpacing
from .vocabulary import (
    ALIGN_APPROXIMATE_RELATIVE,
    BASELINE_FIELDS,
    FLAG_FIELDS,
    MODE_FIELDS,
    QUANTITIES,
    one_line,
    plain,
)

STATE_VERSION = 1
FLOAT64_TYPE = "std_msgs/msg/Float64"


def _modes_text(modal: np.ndarray) -> str:
    """``3.2487 Hz, 32.971 Hz`` (a rigid body, frequency 0, by name) for a notice line."""
    return ", ".join(f"{m[0]:.5g} Hz" if m[0] > 0 else "rigid body" for m in np.asarray(modal))


class PipelineError(ValueError):
    """Unusable call (shape mismatch, incompatible saved state); one-line message."""


@dataclass
class Report:
    """Everything published at one output instant (docs/INTERFACE.md: /diagnostics and CSVs)."""

    time_s: float                     # since the first sample
    modal: np.ndarray                 # (K, 6): f_hz, zeta, gain, f_std, zeta_std, gain_std (NaN before init)
    baseline: np.ndarray              # (K, 3), NaN while not learned
    baseline_std: np.ndarray          # (K, 3)
    flags: np.ndarray                 # (K, 3) bool: confirmed faults (natural_frequency, damping, gain)
    levels: np.ndarray                # (K, 3) int Level per mode and quantity
    directions: list[list[str]]       # (K, 3) "up" | "down" | ""
    events_opened: list[FaultEvent]
    events_closed: list[FaultEvent]
    health: dict[str, Any]            # level, ok, hold, reasons, counters, ...
    phase: str                        # finding modes | initializing | settling | learning | monitoring
    estimating: bool                  # False before the first initialization (modal is NaN)
    notices: list[str] = field(default_factory=list)   # one-line news since the last report (modes found, a failed
                                                        # automatic start) for the node's log / the CLI's stderr
    estimator_health: EstimatorHealth | None = None     # the estimator's own record (None while not estimating);
                                                        # health["estimator"] is its to_dict()
    decisions: list[ModeDecision] = field(default_factory=list)   # per mode: state, reason, holds (core/decision.py)

    @property
    def K(self) -> int:
        return self.modal.shape[0]

    @property
    def mode_levels(self) -> np.ndarray:
        """(K,) worst level per mode (the mode's DiagnosticStatus level)."""
        return self.levels.max(axis=1)

    @property
    def health_level(self) -> Level:
        return Level(int(self.health["level"]))

    def mode_dict(self, i: int) -> dict[str, Any]:
        """Mode ``i`` (0-based) with the /diagnostics mode keys (docs/INTERFACE.md) (numbers; flags bool)."""
        m, b = self.modal[i], self.baseline[i]
        return {
            **{k: float(m[j]) for j, k in enumerate(MODE_FIELDS)},
            **{k: float(b[q]) for q, k in enumerate(BASELINE_FIELDS)},
            **{f"{k}_std": float(self.baseline_std[i, q]) for q, k in enumerate(BASELINE_FIELDS)},
            **{k: bool(self.flags[i, q]) for q, k in enumerate(FLAG_FIELDS)},
            **{f"level_{q}": int(self.levels[i, j]) for j, q in enumerate(QUANTITIES)},
            **{f"direction_{q}": self.directions[i][j] for j, q in enumerate(QUANTITIES)},
        }

    def to_dict(self) -> dict[str, Any]:
        return {"time_s": self.time_s, "phase": self.phase, "estimating": self.estimating,
                "modes": [self.mode_dict(i) for i in range(self.K)],
                "events_opened": [e.to_dict() for e in self.events_opened],
                "events_closed": [e.to_dict() for e in self.events_closed], "health": self.health}


@dataclass
class _Counters:
    samples_in: int = 0
    samples_processed: int = 0        # given to the estimator (initialization, updates, skipped-as-invalid)
    samples_skipped: int = 0          # given as invalid (non-finite or repeated output): no update
    samples_dropped: int = 0          # never given to the estimator (bad stamps, stuck sensor)
    out_of_order: int = 0
    clock_steps: int = 0
    duplicates: int = 0
    nonfinite: int = 0
    outliers: int = 0                 # finite samples of absurd magnitude, given as invalid (MagnitudeGuard)
    filled: int = 0                   # missing grid samples of short gaps, given as invalid (no re-prime)
    repeated: int = 0
    gaps: int = 0
    stuck_episodes: int = 0
    initializations: int = 0
    init_failures: int = 0
    invalid_models: int = 0           # initializations whose model the controller does not stabilize
    reinitializations: int = 0
    data_starts: int = 0              # guesses that gave no valid model, replaced by modes found in the data

    def to_dict(self) -> dict[str, int]:
        return dict(self.__dict__)


EstimatorFactory = Callable[[MonitorSettings], RecursiveEstimator]
"""Builds the estimator for a configuration's modes (default :meth:`.recursive.RecursiveAdditiveSRIVC.from_config`)."""

ABSOLUTE_BOUND = 1e15
"""|value| above which a sample is never data (about 1e9 x any physical signal in SI units)."""
RELATIVE_BOUND = 1e6
"""|value| above this x the running scale (the 99th percentile of the nonzero |value| seen so far) is not data."""
SCALE_QUANTILE = 0.99
"""Quantile of |value| used as the running scale: robust to 1 % outliers, and a signal that idles near its noise
floor for most of the record and then moves (a setpoint starting late) still sets its scale from the motion."""
MAGNITUDE_MIN_SAMPLES = 32    # nonzero samples seen before the relative bound applies
_LOG_BINS_PER_DECADE = 4
_LOG_MIN, _LOG_MAX = -330.0, 310.0


class MagnitudeGuard:
    """Running robust scale of a signal: a histogram of ``log10 |x|`` over every accepted nonzero sample.

    A finite sample is *absurd* when ``|x| > ABSOLUTE_BOUND`` or, once ``MAGNITUDE_MIN_SAMPLES`` nonzero samples were
    seen, ``|x| > RELATIVE_BOUND x`` the ``SCALE_QUANTILE`` quantile of ``|x|`` (to a quarter decade; isolated
    outliers cannot move it).
    """

    def __init__(self) -> None:
        self.hist = np.zeros(int((_LOG_MAX - _LOG_MIN) * _LOG_BINS_PER_DECADE) + 1, dtype=np.int64)
        self.n = 0
        self._scale = math.nan
        self._n_at_median = 0

    def bound(self) -> float:
        """Current magnitude bound (``ABSOLUTE_BOUND`` until enough samples were seen)."""
        if self.n < MAGNITUDE_MIN_SAMPLES:
            return ABSOLUTE_BOUND
        if self.n >= 2 * self._n_at_median or self.n - self._n_at_median >= 4096 or math.isnan(self._scale):
            k = int(np.searchsorted(np.cumsum(self.hist), math.ceil(SCALE_QUANTILE * self.n)))
            self._scale = 10.0 ** (_LOG_MIN + (k + 0.5) / _LOG_BINS_PER_DECADE)
            self._n_at_median = self.n
        return min(ABSOLUTE_BOUND, RELATIVE_BOUND * self._scale)

    def absurd(self, x: np.ndarray) -> np.ndarray:
        """Bool mask of finite samples above the bound (non-finite ones are not flagged here)."""
        return np.isfinite(x) & (np.abs(x) > self.bound())

    def learn(self, x: np.ndarray) -> None:
        """Add accepted samples (finite, not absurd) to the scale."""
        a = np.abs(x[np.isfinite(x)])
        a = a[a > 0.0]
        if a.size:
            k = np.clip(((np.log10(a) - _LOG_MIN) * _LOG_BINS_PER_DECADE).astype(np.int64), 0, self.hist.size - 1)
            self.hist += np.bincount(k, minlength=self.hist.size)
            self.n += int(a.size)

    def get_state(self) -> dict[str, Any]:
        nz = np.flatnonzero(self.hist)
        return {"bins": nz.tolist(), "counts": self.hist[nz].tolist()}

    def set_state(self, d: Mapping[str, Any]) -> None:
        self.hist[:] = 0
        self.hist[np.asarray(d["bins"], dtype=np.int64)] = np.asarray(d["counts"], dtype=np.int64)
        self.n = int(self.hist.sum())
        self._scale, self._n_at_median = math.nan, 0


def _default_factory(cfg: MonitorSettings) -> RecursiveEstimator:
    from .recursive import RecursiveAdditiveSRIVC
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
    def _new_estimator(self) -> RecursiveEstimator:
        est = self._factory(self.cfg)
        est.set_memory(self.memory_s)
        self._est_memory = self.memory_s.copy()
        return est

    def _apply_memory(self) -> None:
        """The estimator's memories: the configured ones, shortened while the fault monitor tracks a detected change
        of a mode (S7, variable forgetting; never below 50 samples). Applied here only."""
        if self.est is None or self.faults is None:
            return
        fast = np.maximum(self.memory_s * self.faults.memory_scale(), 50.0 / self.rate)
        mem = np.minimum(self.memory_s, fast)
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
    def stream_aligner(self) -> Any:
        if self.aligner is None:
            raise PipelineError("no stream aligner configured")
        return self.aligner

    def _set_modes(self, cfg: MonitorSettings) -> None:
        """Estimator, fault and health monitors for the modes of ``cfg`` (none while the modes are searched)."""
        self.cfg = cfg
        self.K = cfg.K
        self.memory_s = np.array([m.memory_s for m in cfg.modes], dtype=float)
        if self.K == 0:                       # automatic start pending: a health monitor for the notes only
            mem = [float(v) for v in cfg.params.get("modes.memory_s", [])] or [DEFAULT_MEMORY_S]
            self.est, self.faults, self.joint = None, None, None
            self.health = HealthMonitor([max(mem)], self.settings, rate_hz=self.rate)
            return
        self.settings.check(self.K)
        self.est = self._new_estimator()
        self.faults = FaultMonitor(self.memory_s, self.settings, structures=cfg.structures)
        self.joint = JointChecker(cfg)
        self.health = HealthMonitor(self.memory_s, self.settings, structures=cfg.structures, rate_hz=self.rate)

    def _switch_modes(self, cfg: MonitorSettings, closed: tuple[str, ...] = ()) -> None:
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
        self.counters = _Counters()
        self.notices: list[str] = []
        self.t0: float | None = None          # absolute time of the first sample
        self.t_last: float | None = None      # absolute time of the last accepted sample
        self.t_stamp_last: float | None = None  # last stamp accepted by step 1 (the aligner may hold samples back)
        self.clock_offset = 0.0                 # added to every stamp since a recorder clock stepped back (s)
        self.spacing = StampSpacing(self.rate)  # loop_rate_hz against the stamps' own spacing
        self.next_publish = 0.0               # time (since t0) of the next report
        self.initialized = False
        self._data_start_tried = False        # guesses replaced by modes from the data (once per run)
        self._order_restarted = False         # a restart after the model-order check (once per run)
        self._start_checked = False           # the automatic start was checked on its window: not again at its init
        self.stuck = False
        self._init_buf: list[tuple[np.ndarray, ...]] = []
        self._init_n = 0
        self.last_y: float | None = None
        self.run_len = 0                      # identical consecutive finite outputs so far
        self.run_start_t = math.nan           # absolute time the current run of identical outputs began
        self._win_n = 0                       # samples / repeated outputs since the last report
        self._win_rep = 0
        self.pending_opened: list[FaultEvent] = []
        self.pending_closed: list[FaultEvent] = []
        self.last_report: Report | None = None
        self.aligner = _make_aligner(self.cfg)
        self._align_notes: list[str] = []     # re-alignments since the last report
        self._align_late = 0
        self._align_prev = (0, 0)             # (samples_out, undecided) at the last report
        self._align_shown: tuple[str, float] | None = None   # last re-alignment note and its report time
        self.magnitude = {name: MagnitudeGuard() for name in ("reference", "input", "output")}
        self.no_model: str | None = None      # why there is no valid model (None: valid, or not tried yet)
        self.model_max_pole = math.nan        # closed-loop spectral radius of the current model with C_d
        self._marked_gaps = 0                 # re-primes the pipeline asked for (others: non-finite filter states)
        self._blind_since: float | None = None
        opts = self.cfg_given.estimator
        self.order_check = ModelOrderCheck(self.rate, opts.order_check_memory_lengths, opts.order_check_relevance)

    def reset(self) -> None:
        """Start over: new estimator (initialized from the next data), no baseline, counters zeroed; without
        guesses the modes are found again on the next data."""
        self._new_run()

    def rebaseline(self) -> list[FaultEvent]:
        """Learn a new baseline from the next healthy window; open events are closed now (and returned)."""
        if self.faults is None:               # modes not found yet: the baseline is learned after the start anyway
            return []
        t = self._rel(self.t_last) if self.t_last is not None else 0.0
        closed = self.faults.rebaseline(t)
        self.pending_closed += closed
        return closed

    @property
    def phase(self) -> str:
        if self.finding_modes:
            return "finding modes"
        return "initializing" if not self.initialized else self.fault_monitor.phase

    # ------------------------------------------------------------------------------------------- runtime params
    def update_params(self, params: Mapping[str, Any]) -> None:
        """Apply runtime-changeable parameters: ``modes.memory_s``, ``publish_rate_hz``, ``faults.*``.

        Raises :class:`PipelineError` (nothing changed) on a bad value.
        """
        fp = {k: v for k, v in params.items() if k.startswith("faults.")}
        if fp:
            try:
                if self.faults is None:       # modes not found yet: the settings the fault monitor will start with
                    new = FaultSettings.from_params({**self.cfg_given.params, **self._fault_changes, **fp})
                    new.check(self.cfg_given.mode_count or None)
                    self.settings = new
                else:
                    self.faults.update_settings(fp)
                    self.settings = self.faults.settings
            except ValueError as exc:
                raise PipelineError(str(exc)) from None
            self._fault_changes.update(fp)
            self.health.settings = self.settings
        if "modes.memory_s" in params and self.K == 0:
            self._set_memory_param(params["modes.memory_s"])
        elif "modes.memory_s" in params:
            mem = np.asarray(params["modes.memory_s"], dtype=float).ravel()
            if mem.size == 1:                 # one value for all modes, as in the params file
                mem = np.full(self.K, float(mem[0]))
            if mem.shape != (self.K,) or not np.all(mem * self.rate >= 2.0):
                raise PipelineError(f"modes.memory_s must list {self.K} memories of at least two samples")
            self.memory_s = mem
            self.fault_monitor.set_memory(mem)
            self.health.memory_s = mem
            self._est_memory = np.full(self.K, math.nan)
            self._apply_memory()
        if "publish_rate_hz" in params:
            rate = float(params["publish_rate_hz"])
            if not (rate > 0 and math.isfinite(rate)):
                raise PipelineError("publish_rate_hz must be > 0")
            self.publish_period = 1.0 / rate

    def _set_memory_param(self, value: Any) -> None:
        """``modes.memory_s`` changed before the modes are known: the memories the found modes will get."""
        mem = [float(v) for v in np.atleast_1d(np.asarray(value, dtype=float))]
        if not mem or not all(m * self.rate >= 2.0 for m in mem):
            raise PipelineError("modes.memory_s must list memories of at least two samples")
        self.cfg_given = self.cfg_given.with_memory(mem)
        if self.search is not None:
            self.search.cfg = self.cfg_given

    # ------------------------------------------------------------------------------------------- data path
    def _rel(self, t_abs: float) -> float:
        return float(t_abs - self.t0) if self.t0 is not None else 0.0

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
        t, r, u, y = self._accept_stamps(t, r, u, y)
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

    def _accept_stamps(self, t: np.ndarray, r: np.ndarray, u: np.ndarray,
                       y: np.ndarray) -> tuple[np.ndarray, ...]:
        """Step 1: drop samples with non-finite, duplicate and out-of-order stamps (they never touch the grid)."""
        c = self.counters
        finite_t = np.isfinite(t)
        if self.t0 is None:
            if not finite_t.any():
                c.samples_dropped += t.size
                return t[:0], r[:0], u[:0], y[:0]
            self.t0 = float(t[np.argmax(finite_t)])
        t = self._rebase_clock_steps(t)
        start = -np.inf if self.t_stamp_last is None else self.t_stamp_last
        prev = np.maximum.accumulate(np.concatenate(([start], np.where(finite_t, t, -np.inf))))[:-1]
        ok_t = finite_t & (t > prev)
        if not ok_t.all():
            dup = finite_t & (t == prev)
            n_dup, n_bad = int(dup.sum()), int((~ok_t).sum())
            c.duplicates += n_dup
            c.out_of_order += n_bad - n_dup
            c.samples_dropped += n_bad
            t_note = self._rel(float(np.max(prev[~ok_t]))) if np.isfinite(prev[~ok_t]).any() else 0.0
            if n_dup:
                self.health.note("duplicate_stamps", t_note, f"{c.duplicates} duplicate time stamps dropped")
            if n_bad > n_dup:
                self.health.note("out_of_order", t_note, f"{c.out_of_order} out-of-order or invalid time stamps "
                                 "dropped")
        idx = np.flatnonzero(ok_t)
        if idx.size:
            self.t_stamp_last = float(t[idx[-1]])
            self.spacing.add(t[idx])
            if self.spacing.error:
                self.health.note("time_scale", self._rel(float(t[idx[-1]])), self.spacing.error)
        return t[idx], r[idx], u[idx], y[idx]

    def _rebase_clock_steps(self, t: np.ndarray) -> np.ndarray:
        """A recorder clock stepped back: from a sample on, every stamp is earlier by the same amount while the
        spacing stays the loop's. Those samples are not out of order; their stamps are re-based onto the grid (the
        offset is kept for later batches) and the step is reported, so no data is dropped or shifted."""
        t = t + self.clock_offset if self.clock_offset else t.copy()
        h = 1.0 / self.rate
        last = -np.inf if self.t_stamp_last is None else self.t_stamp_last
        with np.errstate(invalid="ignore"):
            back = np.flatnonzero(np.diff(np.concatenate(([last], t))) < 0.0)    # candidates only: a cheap scan
        for j in back:
            prev = last if j == 0 else float(t[j - 1])
            if not (math.isfinite(t[j]) and math.isfinite(prev)) or t[j] >= prev:
                continue
            regular = j + 1 < t.size and abs((t[j + 1] - t[j]) - h) <= CLOCK_STEP_SPACING_TOL * h
            if not regular:
                continue            # a lone out-of-order stamp: dropped by the caller
            step = prev + h - float(t[j])
            t[j:] += step
            self.clock_offset += step
            self.counters.clock_steps += 1
            self.health.note("clock_step", self._rel(prev), f"time stamps stepped back by {1e3 * step:.4g} ms at "
                             f"t={self._rel(prev):.3f} s: re-based onto the sample grid (no sample dropped)")
        return t

    def _ingest_aligned(self, blk: AlignedBlock) -> list[Report]:
        """Samples released by the aligner: its findings become health notes, then the usual validation."""
        st = self.stream_aligner.stats
        self._align_notes += [msg for _, msg in st.events]
        st.events.clear()
        if st.late > self._align_late:
            # a shift found after misaligned samples reached the estimator: their filter states are wrong
            n_late = st.late - self._align_late
            self._align_late = st.late
            t_abs = float(blk.t[0]) if blk.n else (self.t_last or 0.0)
            self.health.note("misaligned", self._rel(t_abs), f"{n_late} samples reached the estimator misaligned "
                             "before the shift was detected (estimator re-primed)")
            if self.initialized:
                self.estimator.mark_gap()
        if blk.n == 0:
            return []
        assert blk.r is not None            # the stream aligner runs in closed loop only (it needs r)
        return self._ingest(blk.t, blk.r, blk.u, blk.y, aligner_invalid=blk.invalid)

    def _ingest(self, ta: np.ndarray, ra: np.ndarray, ua: np.ndarray, ya: np.ndarray,
                aligner_invalid: np.ndarray | None = None) -> list[Report]:
        """Validation (values, gaps, stuck sensor), estimation and reports on stamp-checked samples."""
        reports: list[Report] = []
        c = self.counters
        s = self.settings
        # 2. values: non-finite samples and samples of absurd magnitude are given to the estimator as invalid
        # (skipped, grid kept); so are the missing samples of a short gap (filled in, no re-prime)
        ta, ra, ua, ya, filled = self._fill_short_gaps(ta, ra, ua, ya)
        if aligner_invalid is not None and filled.any():
            grown = np.zeros(filled.size, dtype=bool)
            grown[~filled] = aligner_invalid
            aligner_invalid = grown
        n = ta.size
        fin, absurd = self._valid_values(ta, ra, ua, ya, filled)
        # 3. gaps: spacing above (1 + tol) h between accepted samples
        prev_t = np.concatenate(([self.t_last if self.t_last is not None else ta[0]], ta[:-1]))
        gap = (ta - prev_t) > (1.0 + s.health_gap_tolerance) * self.h
        # 4. repeated outputs and stuck runs (on the finite samples)
        fi = np.flatnonzero(fin)
        rep = np.zeros(n, dtype=bool)
        run_len = np.zeros(n, dtype=np.int64)
        run_t0 = np.full(n, np.nan)
        if fi.size:
            yf = ya[fi]
            prev_y = np.concatenate(([np.nan if self.last_y is None else self.last_y], yf[:-1]))
            eq = yf == prev_y
            k = np.arange(fi.size)
            last_reset = np.maximum.accumulate(np.where(~eq, k, -1))
            rl = np.where(last_reset >= 0, k - last_reset + 1, self.run_len + k + 1)
            rt = np.where(last_reset >= 0, ta[fi[np.maximum(last_reset, 0)]], self.run_start_t)
            rep[fi], run_len[fi], run_t0[fi] = eq, rl, rt
            self.last_y, self.run_len, self.run_start_t = float(yf[-1]), int(rl[-1]), float(rt[-1])
        stuck_n = max(s.health_stuck_min_samples, int(math.ceil(s.health_stuck_s * self.rate)))
        stuck = run_len >= stuck_n
        # carry stuck status through non-finite samples inside a stuck run
        if not fin.all():
            st_f = np.where(fin, stuck.astype(float), np.nan)
            st_f = _ffill(st_f, 1.0 if self.stuck else 0.0)
            stuck = st_f > 0.5
        valid = fin & ~(rep & s.health_repeated_output_is_missing)
        nonfin = ~fin & ~filled & ~absurd
        if aligner_invalid is not None:   # set aside by the aligner (re-alignment, lost sample): not sensor NaNs
            nonfin &= ~aligner_invalid
        n_nonfin = int(nonfin.sum())
        if n_nonfin:
            c.nonfinite += n_nonfin
            self.health.note("nonfinite", self._rel(float(ta[np.flatnonzero(nonfin)[-1]])),
                             f"{c.nonfinite} non-finite sensor samples skipped")
        n_fill = int(filled.sum())
        if n_fill:
            c.filled += n_fill
            self.health.note("data_gap", self._rel(float(ta[np.flatnonzero(filled)[-1]])),
                             f"{c.filled} missing samples of short gaps filled as invalid samples (grid kept)")
        # 5. blocks between gaps and stuck transitions
        cuts = np.flatnonzero(gap | np.concatenate(([stuck[0] != self.stuck], stuck[1:] != stuck[:-1])))
        bounds = [0, *[int(j) for j in cuts if j > 0], n]
        for a, b in zip(bounds[:-1], bounds[1:], strict=True):
            if gap[a]:
                c.gaps += 1
                self._on_break(f"data gap of {ta[a] - prev_t[a]:.4g} s", "data_gap", float(ta[a]))
            if stuck[a]:
                if not self.stuck:
                    c.stuck_episodes += 1
                    self.stuck = True
                c.samples_dropped += b - a
                self.health.note("stuck_sensor", self._rel(float(ta[b - 1])), "stuck sensor: output constant at "
                                 f"{self.last_y:.6g} since t={self._rel(float(run_t0[a])):.3f} s; samples withheld")
                self._advance(ta, ra, ua, ya, valid, a, b, feed=False, reports=reports)
                continue
            if self.stuck:
                self.stuck = False
                self._on_break("sensor recovered", None, float(ta[a]))
            c.repeated += int(rep[a:b].sum())
            self._advance(ta, ra, ua, ya, valid, a, b, feed=True, reports=reports, repeated=rep)
        self.t_last = float(ta[-1])
        return reports

    def _fill_max_samples(self) -> int:
        """Longest gap (missing samples) filled with invalid samples instead of a re-prime: 5 % of the shortest
        period of the modelled modes (the held input then barely moves the filter states), at least one sample."""
        f = self._modal()[:, 0] if self.initialized else np.array(
            [m.natural_frequency_hz for m in self.cfg.modes if m.natural_frequency_hz], float)
        f = f[np.isfinite(f) & (f > 0)] if f.size else f
        if f.size == 0:
            return 1
        return max(1, int(math.floor(0.05 * self.rate / float(f.max()))))

    def _fill_short_gaps(self, ta: np.ndarray, ra: np.ndarray, ua: np.ndarray, ya: np.ndarray,
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Insert the missing grid samples of short gaps (:meth:`_fill_max_samples`) as NaN samples."""
        filled = np.zeros(ta.size, dtype=bool)
        if self.t_last is None and ta.size < 2:
            return ta, ra, ua, ya, filled
        prev_t = np.concatenate(([self.t_last if self.t_last is not None else ta[0]], ta[:-1]))
        dt = ta - prev_t
        missing = np.rint(dt / self.h).astype(np.int64) - 1
        short = (dt > (1.0 + self.settings.health_gap_tolerance) * self.h) & (missing >= 1)
        if not short.any():
            return ta, ra, ua, ya, filled
        short &= missing <= self._fill_max_samples()
        if not short.any():
            return ta, ra, ua, ya, filled
        reps = np.where(short, missing + 1, 1)
        pos = np.repeat(np.arange(ta.size), reps)                     # source sample of every output row
        k_in = np.arange(pos.size) - np.repeat(np.cumsum(reps) - reps, reps)   # 0..reps-1 within a group
        is_fill = k_in < reps[pos] - 1
        frac = (k_in + 1) / reps[pos]
        t_out = np.where(is_fill, prev_t[pos] + frac * dt[pos], ta[pos])
        nan = np.full(pos.size, np.nan)
        return (t_out, np.where(is_fill, nan, ra[pos]), np.where(is_fill, nan, ua[pos]),
                np.where(is_fill, nan, ya[pos]), is_fill)

    def _valid_values(self, ta: np.ndarray, ra: np.ndarray, ua: np.ndarray, ya: np.ndarray,
                      filled: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(valid, absurd): finite samples of plausible magnitude (:class:`MagnitudeGuard`), and the finite ones of
        absurd magnitude (counted as outliers and noted on health). An absurd value is set to NaN in place: it is
        never data (the estimator holds that signal at its last value, the initialization skips the sample)."""
        sigs = [("input", ua), ("output", ya)] + ([("reference", ra)] if self.cfg.closed_loop else [])
        fin = np.ones(ta.size, dtype=bool)
        absurd = np.zeros(ta.size, dtype=bool)
        bad_of = {}
        worst = ""
        for name, x in sigs:
            fin &= np.isfinite(x)
            bad = bad_of[name] = self.magnitude[name].absurd(x)
            if bad.any():
                j = int(np.argmax(np.where(bad, np.abs(x), -1.0)))
                worst = (f"|{name}| = {abs(float(x[j])):.3g} > {self.magnitude[name].bound():.3g} at "
                         f"t={self._rel(float(ta[j])):.3f} s")
            absurd |= bad
        ok = fin & ~absurd & ~filled
        for name, x in sigs:
            self.magnitude[name].learn(x[ok])
            x[bad_of[name]] = np.nan
        n_out = int(absurd.sum())
        if n_out:
            self.counters.outliers += n_out
            self.health.note("outlier", self._rel(float(ta[np.flatnonzero(absurd)[-1]])),
                             f"{self.counters.outliers} samples of absurd magnitude skipped as invalid "
                             f"(latest {worst}; bound {RELATIVE_BOUND:g} x the 99th percentile of |value| so far, "
                             f"at most {ABSOLUTE_BOUND:g})")
        return fin & ~absurd, absurd

    def _on_break(self, why: str, kind: str | None, t_abs: float) -> None:
        """The sample grid is broken: re-prime the estimator ([RA-SRIVC] Algorithm 2 step 1) or restart the init
        buffer."""
        if kind is not None:
            self.health.note(kind, self._rel(t_abs), f"{why} (estimator re-primed)")
        if self.initialized:
            self.estimator.mark_gap()
            self._marked_gaps += 1
            self.joint_checker.recent.clear()
        else:
            self._init_buf, self._init_n = [], 0
            if self.finding_modes:           # the search needs contiguous data too: its window starts again
                self.mode_search.clear()

    def _advance(self, ta, ra, ua, ya, valid, a: int, b: int, *, feed: bool, reports: list[Report],
                 repeated: np.ndarray | None = None) -> None:
        """Feed samples ``[a, b)`` (or only pass their time when ``feed`` is False), reporting on the way.

        A report at instant T is made once every accepted sample before T was processed; instants that
        fall inside a gap are collapsed into one report.
        """
        assert self.t0 is not None          # set by the first accepted sample, before any is advanced
        while a < b:
            t_next = self.t0 + self.next_publish
            j = a + int(np.searchsorted(ta[a:b], t_next, side="left"))
            if feed and not self.initialized:
                j = min(j, a + (self.mode_search.need() if self.finding_modes else self.init_samples - self._init_n))
            if j > a:
                if feed:
                    self._consume(ra[a:j], ua[a:j], ya[a:j], valid[a:j], float(ta[j - 1]))
                    if repeated is not None:    # counted in the report window the samples belong to
                        self._win_rep += int(repeated[a:j].sum())
                a = j
                continue
            self._report(reports, self._rel(float(ta[a])))

    def _consume(self, r: np.ndarray, u: np.ndarray, y: np.ndarray, valid: np.ndarray, t_end: float) -> None:
        c = self.counters
        n = u.size
        c.samples_processed += n
        c.samples_skipped += int((~valid).sum())
        self._win_n += n
        if self.finding_modes:
            self._search_modes(r, u, y, valid, t_end)
        else:
            self._feed(r, u, y, valid, t_end)

    def _feed(self, r: np.ndarray, u: np.ndarray, y: np.ndarray, valid: np.ndarray, t_end: float) -> None:
        """Samples to the estimator: the first ``init_duration_s`` to the offline initialization, then updates."""
        a, n = 0, u.size
        while a < n:
            if self.initialized:
                self.estimator.update(r[a:], u[a:], y[a:], valid[a:])
                self.joint_checker.add(r[a:], u[a:], np.where(valid[a:], y[a:], np.nan),
                                       float(self.fault_monitor.memory_s.max()))
                self._check_order(r[a:], u[a:], y[a:], valid[a:], t_end)
                return
            b = min(n, a + self.init_samples - self._init_n)
            yv = np.where(valid[a:b], y[a:b], np.nan)   # invalid samples are NaN for the offline init (it skips them)
            self._init_buf.append((r[a:b].copy(), u[a:b].copy(), yv))
            self._init_n += b - a
            a = b
            if self._init_n >= self.init_samples:
                rb, ub, yb = (np.concatenate([blk[q] for blk in self._init_buf]) for q in range(3))
                self._init_buf, self._init_n = [], 0
                self._initialize(rb, ub, yb, t_end)

    def _check_order(self, r: np.ndarray, u: np.ndarray, y: np.ndarray, valid: np.ndarray, t_end: float) -> None:
        """Model-order check (:mod:`.adequacy`) on the first window of contiguous data after the initialization, once
        per run, against the estimate at its end; its finding goes on health (:meth:`ModelOrderCheck.apply`)."""
        if self.order_check.add(r, u, y, valid, self._rel(t_end), float(self.memory_s.max())):
            window = self.order_check.window()
            line = self.order_check.run(self._modal(), self.cfg, self.settings.min_change)
            if line is not None:
                self.notices.append(line)
            res = self.order_check.result
            if res is not None and res.flagged and not res.wrong_delay and not self._order_restarted:
                # (a wrong input delay is the configuration's: modes found again with it would misfit the same way)
                self._order_restarted = True
                try:
                    self._restart_from_data(*window, t_end, res)
                except Exception as exc:  # noqa: BLE001 - a failed restart is a line, never a crash
                    self.notices.append(f"restart from the data failed ({type(exc).__name__}: "
                                        f"{str(exc).splitlines()[0][:120] if str(exc) else ''}); the model stays "
                                        "flagged")

    def _restart_from_data(self, r: np.ndarray, u: np.ndarray, y: np.ndarray, t_end: float, res: Any,
                           initial: bool = False) -> None:
        """The model-order check found the model wrong for the data (``misfit`` or ``too_low``; a
        wrong optimum can look like either): the modes are found again on the check's window (:mod:`.modefind`; K
        automatic when the run found its modes itself, else the configured K and integrators) and adopted only if
        the same check on that window passes them; the estimator is then initialized on the window and the fault
        monitors start over (a baseline learned on a wrong model is no baseline). Once per run. Otherwise the
        flag stays on health: a model that misfits is never reported as healthy."""
        from .adequacy import check_model_order
        from .autostart import FoundModes
        from .modefind import SCAN_TOL, autostart_config

        auto = self.search is not None
        closed = bool(self.cfg.closed_loop)
        t_rel = self._rel(t_end)
        a, b = res.window_s
        where = f"t={a:.1f}–{b:.1f} s"
        c0 = time.perf_counter()
        try:
            new, found = autostart_config(self.cfg_given if auto else self.cfg, r if closed else None, u, y,
                                          count=None if auto else self.K, refit_tol=SCAN_TOL)
        except ValueError as exc:
            self.notices.append(f"restart from the data on {where} failed: {exc}; the model stays flagged")
            return
        if not auto and sorted(m.integrators for m in new.modes) != sorted(m.integrators for m in self.cfg.modes):
            self.notices.append(f"restart from the data on {where}: the modes found have other integrators than "
                                "modes.integrators; not used, the model stays flagged")
            return
        check = check_model_order(found.thetas, found.structures, u, y, self.rate, r=r if closed else None,
                                  **self._check_keywords())
        modes = _modes_text(found.modal)
        if check.flagged or check.state == "skipped":
            self.notices.append(f"restart from the data on {where}: the {found.K} mode(s) found there ({modes}) "
                                f"do not pass the check either ({check.state}); the model stays flagged")
            return
        self._switch_modes(new)
        if auto:
            attempts = self.mode_search.found.attempts + 1 if self.mode_search.found is not None else 1
            modal = np.array([[m.natural_frequency_hz, m.damping_ratio, m.gain] for m in new.modes], dtype=float)
            self.mode_search.found = FoundModes(modal, [int(m.integrators) for m in new.modes], (a, b),
                                           f"restart after the model-order check: {found.message}",
                                           time.perf_counter() - c0, attempts)
        self.initialized = False
        self._marked_gaps = 0
        failure = self._fit_initial(r, u, y)
        if failure is not None:
            self._no_valid_model(t_rel, f"restart from the data: {failure[1]}")
            return
        self.initialized = True
        self.no_model = None
        self.health.clear_reference(self._modal())
        check.window_s, check.frf = (a, b), None
        if initial:               # the initialization window: the regular check still runs on the data that follow
            self.order_check.start_result = None
        else:
            self.order_check.result = check
        stage = "check of the initial model" if initial else "model-order check"
        line = (f"restarted from the data after the {stage} ({res.message}): the {self.K} mode(s) found "
                f"on {where} ({modes}) fit it; fault monitoring starts over")
        self.health.note("restart_from_data", t_rel, line)
        self.notices.append(line)
        self.counters.data_starts += 1

    def _search_modes(self, r: np.ndarray, u: np.ndarray, y: np.ndarray, valid: np.ndarray, t_end: float) -> None:
        """Automatic start (no guesses; :mod:`.autostart`): buffer the window, search it when full; once the modes
        are found the estimator gets the buffered samples as the guess path would have given them."""
        search, t_rel = self.mode_search, self._rel(t_end)
        if search.waiting(t_rel):         # back-off after repeated failures: these samples are not searched
            return
        search.add(r, u, y, valid, t_end, t_rel)
        if search.need() > 0:
            return
        new, line = search.run(t_rel)
        self.notices.append(line)
        if new is None:
            search.clear()
            self.health.note("no_modes", t_rel, line)
            return
        self._adopt_modes(new, t_rel)
        blocks = search.take()
        self._check_start(blocks, search)
        for blk in blocks:
            self._feed(blk.r, blk.u, blk.y, blk.valid, blk.t_end)

    def _check_start(self, blocks: list, search: ModeSearch) -> None:
        """The automatic start's model against its own window (:func:`.adequacy.check_start`): a start that misfits
        it is flagged on health at once (the regular check, on later data, may then restart from the data)."""
        from .adequacy import check_start

        found, closed = search.evidence, bool(self.cfg.closed_loop)
        if found is None or search.found is None:
            return
        self._start_checked = True
        r, u, y = (np.concatenate([getattr(b, k) for b in blocks]) for k in ("r", "u", "y"))
        y = np.where(np.concatenate([b.valid for b in blocks]), y, np.nan)
        try:
            res = check_start(found, r if closed else None, u, y, self.rate, **self._check_keywords())
        except Exception as exc:  # noqa: BLE001 - a failed check is a line, never a crash
            self.notices.append(f"check of the automatic start failed ({type(exc).__name__})")
            return
        if res is not None and res.flagged:
            self._flag_start(res, search.found.window_s, "the automatic start")

    def _check_keywords(self) -> dict[str, Any]:
        """The model checks' (:mod:`.adequacy`) keywords from this run's configuration."""
        closed = bool(self.cfg.closed_loop)
        return {"controller": self.cfg.controller if closed else None, "input_delay": self.cfg.input_delay_samples,
                "min_change": self.settings.min_change, "relevance": self.order_check.relevance,
                "max_iterations": self.cfg.estimator.init_max_iterations}

    def _flag_start(self, res: Any, window_s: tuple[float, float], what: str) -> None:
        """A start that misfits its own window: on health until the regular check runs, and a notice."""
        res.window_s, res.frf = window_s, None
        self.order_check.start_result = res
        a, b = window_s
        self.notices.append(f"model check of {what} on t={a:.1f}–{b:.1f} s: {res.message}")

    def _adopt_modes(self, cfg: MonitorSettings, t_rel: float) -> None:
        """Build estimator and monitors for the modes found; health notes so far are kept (the failed searches'
        ones are closed)."""
        self._switch_modes(cfg, closed=("no_modes", "initializing"))
        found = self.mode_search.found
        what = "no modes" if found is None else found.describe()
        self.health.note("initializing", t_rel, f"no mode guesses: {what}; initializing the estimator")
        self._marked_gaps = 0

    def _initialize(self, r: np.ndarray, u: np.ndarray, y: np.ndarray, t_end: float) -> None:
        """Offline initialization + filter priming on the buffered data ([RA-SRIVC] Algorithm 2 step 1).

        Guesses are a start, not the answer: when they give no valid model (the fit fails, or
        ``C_d`` does not stabilize it), the modes are found in the same window instead (:mod:`.modefind`, K and
        ``modes.integrators`` as configured: the structure is knowledge, the numbers are guesses), once per run,
        with a health note; a model from the data that fails too leaves the pipeline
        without a model (nothing published) and it initializes again on new data."""
        t_rel = self._rel(t_end)
        start_checked, self._start_checked = self._start_checked, False    # for this initialization only
        failure = self._fit_initial(r, u, y)
        if failure is not None and self.search is None and not self._data_start_tried:
            self._data_start_tried = True
            if self._start_from_data(r, u, y, t_rel, failure[1]):
                failure = self._fit_initial(r, u, y)
        if failure is not None:
            kind, why = failure
            if kind == "invalid":
                self._no_valid_model(t_rel, why)
                return
            self.health.note("reinitializing", t_rel, f"initialization failed ({why}); retrying on the next data")
            self.est = self._new_estimator()
            self._marked_gaps = 0
            return
        self.initialized = True
        self.no_model = None
        modal = self._modal()
        if self.health.reference_modal is None and np.all(np.isfinite(modal[:, :3])):
            self.health.clear_reference(modal)
        if not start_checked:      # the automatic start's model was checked on its search window already
            self._check_initial_model(r, u, y, t_end)

    def _check_initial_model(self, r: np.ndarray, u: np.ndarray, y: np.ndarray, t_end: float) -> None:
        """Every initialization's model against the FRF of its own window (:func:`.adequacy.check_initial_model`, the
        automatic start's check): a model that misfits the data it was fitted on -- guesses that led the offline fit
        to a wrong optimum, a re-initialization after a divergence that lands on one -- is flagged on health from its
        first estimate, instead of being reported healthy until the regular check's window is full (which repeated
        divergences may never let happen), and the modes are found again on the window (once per run, as after the
        regular check)."""
        from .adequacy import check_initial_model

        self.order_check.start_result = None
        if not self.order_check.enabled:
            return
        try:
            res = check_initial_model(self.estimator.thetas, list(self.cfg.structures),
                                      r if self.cfg.closed_loop else None, u, y, self.rate, **self._check_keywords())
        except Exception as exc:  # noqa: BLE001 - a failed check is a line, never a crash
            self.notices.append(f"check of the initial model failed ({type(exc).__name__}: {one_line(exc)})")
            return
        if res is None or not res.flagged:
            return
        t_rel = self._rel(t_end)
        self._flag_start(res, (max(t_rel - u.size / self.rate, 0.0), t_rel), "the initial model")
        if not res.wrong_delay and not self._order_restarted:
            self._order_restarted = True
            try:
                self._restart_from_data(r, u, y, t_end, res, initial=True)
            except Exception as exc:  # noqa: BLE001 - a failed restart is a line, never a crash
                self.notices.append(f"restart from the data failed ({type(exc).__name__}: {one_line(exc)}); the "
                                    "model stays flagged")

    def _fit_initial(self, r: np.ndarray, u: np.ndarray, y: np.ndarray) -> tuple[str, str] | None:
        """Initialize the estimator on the window; ``None``, or ``("failed" | "invalid", why)``."""
        try:
            self.estimator.initialize(r, u, y)
        except Exception as exc:  # noqa: BLE001 - any failure of the offline init is a health incident
            self.counters.init_failures += 1
            return "failed", f"{type(exc).__name__}: {str(exc).splitlines()[0][:120] if str(exc) else ''}"
        self.counters.initializations += 1
        problem = self._model_problem("initial model")
        if problem is not None:
            self.counters.invalid_models += 1
            return "invalid", problem
        return None

    def _start_from_data(self, r: np.ndarray, u: np.ndarray, y: np.ndarray, t_rel: float, why: str) -> bool:
        """Replace guesses that gave no valid model by the K modes found in this window; False if none are found."""
        from .modefind import SCAN_TOL, autostart_config

        try:   # the offline initialization that follows refines the start on these samples
            new, found = autostart_config(self.cfg, r if self.cfg.closed_loop else None, u, y, count=self.K,
                                          refit_tol=SCAN_TOL)
        except ValueError as exc:
            self.notices.append(f"the mode guesses gave no valid model ({why}); finding the modes in the data "
                                f"failed too: {exc}")
            return False
        given = sorted(int(m.integrators) for m in self.cfg.modes)
        if sorted(int(m.integrators) for m in new.modes) != given:   # the user's structure is knowledge, not a guess
            self.notices.append(f"the mode guesses gave no valid model ({why}); the modes found in the data have "
                                f"other integrators than modes.integrators {given}: not used")
            return False
        self._switch_modes(new)
        modes = _modes_text(found.modal)
        line = (f"the mode guesses gave no valid model ({why}); started from the {self.K} mode(s) found in the "
                f"data instead ({modes})")
        self.health.note("start_from_data", t_rel, line)
        self.notices.append(line)
        self.counters.data_starts += 1
        return True

    def _model_problem(self, which: str, modal: np.ndarray | None = None) -> str | None:
        """Why the current model is no valid model, or None: it must be finite and, in closed loop, the controller
        ``C_d`` (with the input delay) must stabilize it -- the model's noise-free closed loop generates the
        instrument ([RA-SRIVC] eq. 33) and a plant that ``C_d`` does not stabilize cannot have produced the bounded
        data.
        ``modal``: the current estimate's ``(K, 6)`` when the caller has it (else it is computed)."""
        if modal is None:
            modal = np.asarray(self.estimator.modal(), dtype=float).reshape(self.K, 6)
        if not np.all(np.isfinite(modal[:, :3])):
            return f"{which} is not finite"
        rho = float(self.estimator.closed_loop_max_pole())
        self.model_max_pole = rho
        if math.isnan(rho) or rho < 1.0:
            return None
        return f"{which} destabilizes the loop with C_d: max |closed-loop pole| {rho:.4g}"

    def _no_valid_model(self, t_rel: float, problem: str) -> None:
        """No valid model: drop the estimator (nothing is published) and initialize again on new data."""
        self.no_model = f"no valid model: {problem}; re-initializing on new data"
        self.health.note("no_valid_model", t_rel, self.no_model)
        self.est = self._new_estimator()
        self._marked_gaps = 0
        self.initialized = False
        self._init_buf, self._init_n = [], 0

    # ------------------------------------------------------------------------------------------- reports
    def modal(self) -> np.ndarray:
        """Current (K, 6) estimate ``f_hz, zeta, gain`` and their std; NaN before the first initialization."""
        return self._modal()

    def _modal(self) -> np.ndarray:
        if not self.initialized:     # no valid model (before the first accepted initialization, or after one
            return np.full((self.K, 6), np.nan)   # was rejected / diverged): NaN, never the guesses
        return np.asarray(self.estimator.modal(), dtype=float).reshape(self.K, 6)

    def _report(self, reports: list[Report], t_now: float) -> None:
        """One report at the latest due instant ``<= t_now`` (s since the first sample)."""
        period = self.publish_period
        t_rep = self.next_publish
        if t_now >= t_rep + period:      # a gap swallowed several instants: report only the latest
            t_rep = t_rep + math.floor((t_now - t_rep) / period) * period
        self.next_publish = t_rep + period
        s = self.settings
        if self._win_n > 0 and self._win_rep > s.health_max_repeated_fraction * self._win_n:
            self.health.note("repeated_output", t_rep, f"output repeats its previous value in {self._win_rep} of "
                             f"{self._win_n} samples (dropped or held sensor samples)")
        self._win_n = self._win_rep = 0
        modal = self._modal()
        if self.initialized and self.cfg.closed_loop:    # every report (~0.25 ms for K = 2, delay 4)
            problem = self._model_problem("current model", modal)
            if problem is not None:
                self.counters.invalid_models += 1
                self.counters.reinitializations += 1
                self._no_valid_model(t_rep, problem)
                modal = self._modal()     # NaN: no model
        est_health: EstimatorHealth | None = None
        if self.initialized:
            est_health = self.estimator.health
            if est_health.hold_remaining > 0:
                auto = est_health.reprimes > self._marked_gaps
                self.health.note("repriming", t_rep, "estimator filters re-priming after non-finite filter states"
                                 if auto else "estimator filters re-priming after a data break")
            status = self.health.assess(t_rep, modal, est_health)
        elif self.finding_modes:
            self.health.note("initializing", t_rep, self.mode_search.status_line())
            status = self.health.status(t_rep)
            if set(status.values["issues"]) <= {"initializing"}:
                status.level = Level.STALE    # no model yet, nothing wrong: as a status without data
        else:
            if self.no_model is not None:
                self.health.note("no_valid_model", t_rep, self.no_model)
            self.health.note("initializing", t_rep, f"initializing: collecting {self.cfg.init_duration_s:g} s of "
                             "valid data for the offline initialization")
            status = self.health.status(t_rep)
        if self.initialized:
            upd = self.fault_monitor.update(t_rep, modal, hold=status.hold,
                                            suspect_since=status.values.get("advisory_since"),
                                            mode_hold=status.mode_hold(self.K))
            self.pending_opened += upd.opened
            self.pending_closed += upd.closed
            self._apply_memory()
            joint = None if status.hold else self.joint_checker.step(t_rep, self.faults)
            if joint is not None:
                self.pending_opened += joint.opened
                self.pending_closed += joint.closed
        health = status.to_dict()
        if self.search is not None:
            health["autostart"] = self.search.info()
        until = None if self.faults is None or self.faults.anomaly_since is None else \
            max(self.faults.restricted_until(i) or t_rep for i in range(self.K))
        if until is not None and t_rep < until:
            health["reasons"].append(f"output anomaly since t={self.fault_monitor.anomaly_since:.1f} s (residual "
                                     f"variance jump or projection storm): until t={until:.1f} s only a fault that "
                                     "began with it can be confirmed; after that every persistent deviation is judged "
                                     "against the baseline")
            health["level"] = max(int(health["level"]), int(Level.WARN))
            health["ok"] = False
        self._alignment_health(health, t_rep)
        health["anomaly_since"] = None if self.faults is None else self.faults.anomaly_since
        self._health_extras(health, status.hold, t_rep)
        decisions = self._decisions(status)
        health["modes"] = [d.to_dict() for d in decisions]
        self.order_check.apply(health, Level.WARN)
        health.update(self.counters.to_dict())
        health["estimator"] = {} if est_health is None else est_health.to_dict()
        health["stuck"] = self.stuck
        health["baseline_source"] = None if self.faults is None or self.faults.baseline is None else \
            self.faults.baseline.source
        if self.spacing.error:           # the model's time scale contradicts the stamps: no number
            modal = np.full_like(modal, np.nan)
        health["time_scale"] = self.spacing.error or None
        rep = Report(time_s=t_rep, modal=modal, **self._fault_fields(), events_opened=self.pending_opened,
                     events_closed=self.pending_closed, health=health, phase=self.phase,
                     estimating=self.initialized, notices=self.notices, estimator_health=est_health,
                     decisions=decisions)
        reports.append(rep)
        self.last_report = rep
        self.pending_opened, self.pending_closed, self.notices = [], [], []
        if self.initialized and "divergence" in status.values.get("new_issues", []):
            self._reinitialize(t_rep)

    def _decisions(self, status: HealthStatus) -> list[ModeDecision]:
        """Each mode's decision state at this report (:mod:`.decision`): the one account of what the tests did."""
        if self.faults is None:
            return []
        holds = list(status.holds)
        if self.faults.phase == "learning" and not status.hold:
            holds = []          # holds scoped to one mode do not pause the baseline window (its spread shows them)
        holds += [Hold("joint_check", f"a {QUANTITIES[q].replace('_', ' ')} deviation awaits the joint check's support "
                       "(the excitation or an abrupt change leaves the recursion's split between quantities open)",
                       since, math.inf, (i,)) for i, q, since in self.faults.awaiting_joint()]
        restricted = [self.faults.restricted_until(i) for i in range(self.K)]
        return decide(self.faults.phase, self.initialized, [[tst.state for tst in row] for row in self.faults.tests],
                      holds, restricted, no_model_reason=self.no_model or "initializing")

    def _fault_fields(self) -> dict[str, Any]:
        """Baseline, flags, levels and directions of a report ((0, 3) while the modes are not known)."""
        if self.faults is None:
            return {"baseline": np.zeros((0, 3)), "baseline_std": np.zeros((0, 3)),
                    "flags": np.zeros((0, 3), dtype=bool), "levels": np.zeros((0, 3), dtype=int), "directions": []}
        b, bs = self.faults.baseline_arrays()
        return {"baseline": b, "baseline_std": bs, "flags": self.faults.flags, "levels": self.faults.levels,
                "directions": self.faults.directions}

    def _alignment_health(self, health: dict[str, Any], t_rep: float) -> None:
        """What the stream aligner found since the last report (non-holding: corrected data are valid data)."""
        if self.aligner is None:
            health["alignment"] = {"mode": "off"}
            return
        st = self.aligner.stats
        out0, und0 = self._align_prev
        n_out, n_und = st.samples_out - out0, st.undecided - und0
        self._align_prev = (st.samples_out, st.undecided)
        rel = st.relative_residual
        health["alignment"] = {"mode": "invariant", "verified": self.aligner.verified, **st.to_dict()}
        notes = []
        if self._align_notes:      # shown for ALIGN_NOTE_HOLD_S: a 1 Hz /diagnostics must not miss it
            self._align_shown = ("; ".join(self._align_notes) + " (corrected before estimation)"
                                 if len(self._align_notes) < 4 else f"{len(self._align_notes)} re-alignments "
                                 f"since t={t_rep:.1f} s (lost or repeated messages, corrected before estimation)",
                                 t_rep)
            self._align_notes = []
        if self._align_shown is not None and t_rep - self._align_shown[1] < ALIGN_NOTE_HOLD_S:
            notes.append(self._align_shown[0])
        if n_out and n_und > ALIGN_UNDECIDED_FRACTION * n_out:
            notes.append(f"alignment not verifiable for {n_und} of {n_out} samples: the controller invariant "
                         "u = C_d(q)(r - y) does not separate the shifts (feedforward, saturation or a different "
                         "controller?); pairing kept as received")
        if math.isfinite(rel) and rel > ALIGN_APPROXIMATE_RELATIVE:
            notes.append(f"controller invariant u = C_d(q)(r - y) holds only to {rel:.2g} relative (rounding gives "
                         "~1e-16): check controller.numerator/denominator")
        if notes:
            health["reasons"] = [*health["reasons"], *notes]
            health["level"] = max(int(health["level"]), int(Level.WARN))
            health["ok"] = False

    def _health_extras(self, health: dict[str, Any], hold: bool, t_rep: float) -> None:
        """Model validity, blind time of the fault tests and baseline trust on the report's health."""
        health["model_valid"] = self.initialized
        health["no_model_reason"] = None if self.initialized else (
            "finding modes (no guesses)" if self.finding_modes else (self.no_model or "not initialized yet"))
        health["closed_loop_max_pole"] = self.model_max_pole if self.initialized else math.nan
        if self.faults is None:
            health["blind_since"], health["baseline_trusted"], health["baseline_note"] = None, False, ""
            return
        paused = self.faults.baseline is None and self.faults.learner.n > 0 and self.faults.learner.paused
        tests_on = self.initialized and (self.faults.phase in ("learning", "monitoring") or paused)
        if hold and tests_on:
            if self._blind_since is None:
                self._blind_since = t_rep
            health["reasons"].append(f"fault tests held (blind) since t={self._blind_since:.1f} s" + (
                f"; baseline window paused ({self.faults.learner.elapsed_s:.1f} s learned, kept)" if paused else ""))
        elif not hold:
            self._blind_since = None
        health["blind_since"] = self._blind_since
        self._identifiability_health(health)
        base = self.faults.baseline
        health["baseline_trusted"] = self.faults.baseline_trusted
        health["baseline_note"] = "" if base is None else base.note
        if base is not None and not base.trusted:
            health["reasons"].append(base.note)
            health["level"] = max(int(health["level"]), int(Level.WARN))
            health["ok"] = False

    def _identifiability_health(self, health: dict[str, Any]) -> None:
        """S6 on the health: what the excitation does not identify jointly, and resonance-peak changes (a change
        of a mode whose gain and damping cannot be told apart is reported here, never as a gain or damping event)."""
        verdict = self.fault_monitor.joint
        health["joint_check"] = None if verdict is None else {
            "armed": self.fault_monitor.joint_armed,
            "armed_modes": [int(i) + 1 for i in np.flatnonzero(self.fault_monitor.joint_armed_modes)],
            "coupling": verdict.coupling_lines(self.fault_monitor.joint_armed_modes,
                                               applicable_mask(self.cfg.structures)),
            "t": verdict.t, "converged": verdict.converged,
            "not_identifiable": verdict.not_identifiable(applicable_mask(self.cfg.structures)),
            "peak_changes": verdict.peak_lines()}
        t_multi = self.fault_monitor.joint_several_modes_t
        if math.isfinite(t_multi) and self.fault_monitor.anomaly_since is not None:
            health["reasons"].append(f"output anomaly: the joint fit of the data after it moves several modes at once "
                                     f"(t={t_multi:.1f} s), which no single structural change explains (a sensor bias "
                                     "or drift?): not confirmed as a fault")
            health["level"] = max(int(health["level"]), int(Level.WARN))
            health["ok"] = False
        if verdict is None or not self.fault_monitor.joint_armed:
            return
        peaks = verdict.peak_lines()
        if peaks:
            health["reasons"].append("structural change, gain and damping not separately identifiable from this "
                                     "excitation: " + "; ".join(peaks))
            health["level"] = max(int(health["level"]), int(Level.WARN))
            health["ok"] = False

    def _reinitialize(self, t_rel: float) -> None:
        """Divergence: a fresh estimator initialized on the next data; baseline and events are kept."""
        self.est = self._new_estimator()
        self._marked_gaps = 0
        self.initialized = False
        self._init_buf, self._init_n = [], 0
        self.counters.reinitializations += 1
        self.no_model = "estimator diverged: re-initializing on new data"
        self.health.note("reinitializing", t_rel, self.no_model)

    # ------------------------------------------------------------------------------------------- state
    def get_state(self) -> dict[str, Any]:
        """Estimator, baseline, fault tests, health and clock as JSON-serializable data.

        A partially filled initialization buffer (or search window) is not saved (initialization restarts on new
        data); a restored running estimator re-primes on the first samples (they follow a gap). Modes found by the
        automatic start are saved (``found_modes``) and restored into a pipeline configured without guesses.
        """
        est = None
        if self.initialized:
            est = {k: plain(v) for k, v in self.estimator.get_state().items()}
        found = self.search.found if self.search is not None else None
        return {
            "version": STATE_VERSION, "K": self.K, "loop_rate_hz": self.rate, "model": self._model_record(),
            "estimator": est, "found_modes": None if found is None else found.to_dict(),
            "faults": None if self.faults is None else self.faults.get_state(), "health": self.health.get_state(),
            "pipeline": {"t0": self.t0, "t_last": self.t_last, "next_publish": self.next_publish,
                         "counters": self.counters.to_dict(), "memory_s": self.memory_s.tolist(),
                         "stuck": self.stuck, "last_y": self.last_y, "run_len": self.run_len,
                         "run_start_t": self.run_start_t, "t_stamp_last": self.t_stamp_last,
                         "clock_offset": self.clock_offset,
                         "aligner": None if self.aligner is None else self.aligner.get_state(),
                         "magnitude": {k: g.get_state() for k, g in self.magnitude.items()},
                         "no_model": self.no_model},
        }

    def _model_record(self, cfg: MonitorSettings | None = None) -> dict[str, Any]:
        """What a saved estimate is only valid for: rate, loop structure, controller, delay, mode structures."""
        cfg = self.cfg if cfg is None else cfg
        c = cfg.controller
        return {"loop_rate_hz": self.rate, "closed_loop": bool(cfg.closed_loop),
                "controller_numerator": None if c is None else [float(v) for v in c.numerator],
                "controller_denominator": None if c is None else [float(v) for v in c.denominator],
                "input_delay_samples": int(cfg.input_delay_samples),
                "integrators": [int(s.integrators) for s in cfg.structures],
                "orders": [[int(s.n), int(s.m)] for s in cfg.structures]}

    def _check_model_record(self, saved: Any, cfg: MonitorSettings | None = None) -> None:
        """Refuse (one line) a state saved under another model: another controller, delay, loop or structures."""
        if not isinstance(saved, Mapping):
            raise PipelineError("saved state does not record its controller, input delay and mode structures "
                                "(saved by an older version); not restored")
        mine = self._model_record(cfg)
        names = {"loop_rate_hz": "loop_rate_hz", "closed_loop": "closed_loop",
                 "controller_numerator": "controller.numerator", "controller_denominator": "controller.denominator",
                 "input_delay_samples": "input_delay_samples", "integrators": "modes.integrators",
                 "orders": "mode orders"}
        for key, label in names.items():
            if key not in saved:
                raise PipelineError(f"saved state does not record {label}; not restored")
            a, b = saved[key], mine[key]
            same = (a is None) == (b is None) and (a is None or np.array_equal(np.asarray(a, dtype=float),
                                                                               np.asarray(b, dtype=float)))
            if not same:
                raise PipelineError(f"saved state is for {label} {a}, the configuration has {b}; not restored")

    def set_state(self, state: Mapping[str, Any]) -> None:
        """Restore :meth:`get_state` output (same K, rate, controller, input delay, loop and mode structures);
        raises :class:`PipelineError` with a one-line reason otherwise (never a silent restore)."""
        try:
            if int(state["version"]) != STATE_VERSION:
                raise PipelineError(f"saved state version {state['version']} is not {STATE_VERSION}")
            found = FoundModes.from_dict(state["found_modes"]) if state.get("found_modes") else None
            target = self.cfg_given   # modes found by an earlier run's automatic start count as guesses
            if found is not None and self.cfg_given.auto_modes:
                target = self.cfg_given.with_modes(found.modal, found.integrators)
            if int(state["K"]) != target.K or float(state["loop_rate_hz"]) != self.rate:
                raise PipelineError(f"saved state is for K={state['K']} at {state['loop_rate_hz']} Hz, the "
                                    f"configuration has K={target.K or 'from the data'} at {self.rate} Hz")
            self._check_model_record(state.get("model"), target)
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
                self._marked_gaps = self.estimator.health.reprimes
            if self.faults is not None:
                self.faults.set_state(state["faults"])
                # the estimator's saved forgetting already holds a shortened memory (S7): only record it
                self._est_memory = np.minimum(self.memory_s, np.maximum(self.memory_s * self.faults.memory_scale(),
                                                                        50.0 / self.rate))
            self.health.set_state(state["health"])
            self.t0 = None if p["t0"] is None else float(p["t0"])
            self.t_last = None if p["t_last"] is None else float(p["t_last"])
            self.next_publish = float(p["next_publish"])
            self.counters = _Counters(**p["counters"])
            self.stuck = bool(p["stuck"])
            self.last_y = None if p["last_y"] is None else float(p["last_y"])
            self.run_len, self.run_start_t = int(p["run_len"]), float(p["run_start_t"])
            ts = p.get("t_stamp_last", p["t_last"])
            self.t_stamp_last = None if ts is None else float(ts)
            self.clock_offset = float(p.get("clock_offset", 0.0))
            if self.aligner is not None and p.get("aligner") is not None:
                self.aligner.set_state(p["aligner"])
            for k, g in (p.get("magnitude") or {}).items():
                if k in self.magnitude:
                    self.magnitude[k].set_state(g)
            self.no_model = None if self.initialized else p.get("no_model")
        except PipelineError:
            raise
        except (KeyError, TypeError, ValueError) as exc:
            raise PipelineError(f"saved state is incomplete or corrupt ({type(exc).__name__}: {exc})") from None


CLOCK_STEP_SPACING_TOL = 0.1        # a stamp before its predecessor, then a spacing this regular: a clock step
ALIGN_NOTE_HOLD_S = 5.0             # a re-alignment stays in the health reasons this long (report time)
ALIGN_UNDECIDED_FRACTION = 0.5       # report when more than this fraction of a report period is undecidable


def _make_aligner(cfg: MonitorSettings) -> InvariantAligner | None:
    """The controller-invariant aligner when it applies (closed loop, Float64 signals, ``alignment.mode: auto``)."""
    p = cfg.params
    if p.get("alignment.mode", "auto") == "off" or not cfg.closed_loop or cfg.controller is None:
        return None
    if any(sc.type != FLOAT64_TYPE for sc in cfg.signals.values()):
        return None   # stamped inputs (JointState) are paired exactly by their header stamps
    rate = float(cfg.loop_rate_hz)
    lag = int(math.ceil(float(p.get("alignment.lag_s", 0.008)) * rate))
    return InvariantAligner(cfg.controller, rate, max_shift=int(p.get("alignment.max_shift", 3)), lag=lag,
                            switch_nats=float(p.get("alignment.switch_nats", 40.0)))


def _ffill(x: np.ndarray, first: float) -> np.ndarray:
    """Forward-fill NaNs (``first`` before the first finite value)."""
    idx = np.where(np.isnan(x), -1, np.arange(x.size))
    idx = np.maximum.accumulate(idx)
    out = np.where(idx >= 0, x[np.maximum(idx, 0)], first)
    return out

