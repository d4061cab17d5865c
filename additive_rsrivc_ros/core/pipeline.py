"""MonitorPipeline: sample validation + recursive additive SRIVC + fault diagnosis (ROS-free).

The one object the node (``rsrivc_monitor``) and the offline tool (``rsrivc_diagnose``) drive:

1. **Validation** of each incoming sample ``(t, r, u, y)``: non-finite, out-of-order and duplicate stamps
   are dropped; non-finite values and outputs that exactly repeat the previous value (a dropped sample
   held by the receiver) are given to the estimator as *invalid* (no update; the kernel holds the input
   and replaces the output by the model prediction), which keeps the sample grid; a spacing above
   ``(1 + faults.health.gap_tolerance) / loop_rate_hz`` is a data gap and an output constant for
   ``faults.health.stuck_s`` is a stuck sensor (samples withheld). After a gap or a stuck episode the
   estimator's filters are re-primed (``mark_gap``, 000 Algorithm 2 step 1). Garbage never reaches the
   estimator as data.
2. **Initialization**: the first ``init_duration_s`` of valid contiguous data go to the estimator's
   offline initialization (000 Algorithm 2 step 1, 001 eq. 29); then samples are fed in blocks.
3. **Diagnosis** at ``publish_rate_hz``: :class:`..faults.HealthMonitor` (estimator health) and
   :class:`..faults.FaultMonitor` (baseline, sequential tests) produce a :class:`Report`.

Times: ``push`` takes sample times in seconds on any fixed origin (ROS time, bag log time); reports
give ``time_s`` since the first sample ever pushed (kept across :meth:`get_state`/:meth:`set_state`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from .faults import (
    BASELINE_KEYS,
    QUANTITIES,
    FaultEvent,
    FaultMonitor,
    FaultSettings,
    HealthMonitor,
    Level,
)

STATE_VERSION = 1


class PipelineError(ValueError):
    """Unusable call (shape mismatch, incompatible saved state); one-line message."""


@dataclass
class Report:
    """Everything published at one output instant (see ../shared/CONTRACT.md /diagnostics and CSVs)."""

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
    phase: str                        # initializing | settling | learning | monitoring
    estimating: bool                  # False before the first initialization (modal is NaN)

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
        """Mode ``i`` (0-based) with the CONTRACT diagnostics keys (numbers; flags bool)."""
        m, b = self.modal[i], self.baseline[i]
        return {
            "natural_frequency_hz": float(m[0]), "damping_ratio": float(m[1]), "gain": float(m[2]),
            "natural_frequency_hz_std": float(m[3]), "damping_ratio_std": float(m[4]), "gain_std": float(m[5]),
            **{f"baseline_{k}": float(b[q]) for q, k in enumerate(BASELINE_KEYS)},
            **{f"baseline_{k}_std": float(self.baseline_std[i, q]) for q, k in enumerate(BASELINE_KEYS)},
            "fault_natural_frequency": bool(self.flags[i, 0]), "fault_damping": bool(self.flags[i, 1]),
            "fault_gain": bool(self.flags[i, 2]),
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
    duplicates: int = 0
    nonfinite: int = 0
    repeated: int = 0
    gaps: int = 0
    stuck_episodes: int = 0
    initializations: int = 0
    init_failures: int = 0
    reinitializations: int = 0

    def to_dict(self) -> dict[str, int]:
        return dict(self.__dict__)


EstimatorFactory = Callable[[Any], Any]


def _default_factory(cfg: Any) -> Any:
    from .recursive import RecursiveAdditiveSRIVC
    return RecursiveAdditiveSRIVC.from_config(cfg)


class MonitorPipeline:
    """Validation + :class:`RecursiveAdditiveSRIVC` + fault logic; see the module docstring.

    ``push(t, r, u, y)`` accepts any number of samples and returns the reports that fell due. Mode
    numbering in events is 1-based (CONTRACT ``mode <i>``).
    """

    def __init__(self, cfg: Any, *, state: Mapping[str, Any] | None = None,
                 estimator_factory: EstimatorFactory | None = None) -> None:
        self.cfg = cfg
        self.K = cfg.K
        self.rate = float(cfg.loop_rate_hz)
        self.h = 1.0 / self.rate
        self._factory = estimator_factory or _default_factory
        self.settings = FaultSettings.from_params(cfg.params)
        self.settings.check(self.K)
        self.memory_s = np.array([m.memory_s for m in cfg.modes], dtype=float)
        self.publish_period = 1.0 / float(cfg.publish_rate_hz)
        self.init_samples = max(2, int(round(float(cfg.init_duration_s) * self.rate)))
        self._new_run()
        if state is not None:
            self.set_state(state)

    # ------------------------------------------------------------------------------------------- lifecycle
    def _new_estimator(self) -> Any:
        est = self._factory(self.cfg)
        if hasattr(est, "set_memory"):
            est.set_memory(self.memory_s)
        return est

    def _new_run(self) -> None:
        self.est = self._new_estimator()
        self.faults = FaultMonitor(self.memory_s, self.settings, structures=self.cfg.structures)
        self.health = HealthMonitor(self.memory_s, self.settings, structures=self.cfg.structures, rate_hz=self.rate)
        self.counters = _Counters()
        self.t0: float | None = None          # absolute time of the first sample
        self.t_last: float | None = None      # absolute time of the last accepted sample
        self.next_publish = 0.0               # time (since t0) of the next report
        self.initialized = False
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

    def reset(self) -> None:
        """Start over: new estimator (initialized from the next data), no baseline, counters zeroed."""
        self._new_run()

    def rebaseline(self) -> list[FaultEvent]:
        """Learn a new baseline from the next healthy window; open events are closed now (and returned)."""
        t = self._rel(self.t_last) if self.t_last is not None else 0.0
        closed = self.faults.rebaseline(t)
        self.pending_closed += closed
        return closed

    @property
    def phase(self) -> str:
        return "initializing" if not self.initialized else self.faults.phase

    # ------------------------------------------------------------------------------------------- runtime params
    def update_params(self, params: Mapping[str, Any]) -> None:
        """Apply runtime-changeable parameters: ``modes.memory_s``, ``publish_rate_hz``, ``faults.*``.

        Raises :class:`PipelineError` (nothing changed) on a bad value.
        """
        fp = {k: v for k, v in params.items() if k.startswith("faults.")}
        if fp:
            try:
                self.faults.update_settings(fp)
            except ValueError as exc:
                raise PipelineError(str(exc)) from None
            self.settings = self.faults.settings
            self.health.settings = self.settings
        if "modes.memory_s" in params:
            mem = np.asarray(params["modes.memory_s"], dtype=float)
            if mem.shape != (self.K,) or not np.all(mem * self.rate >= 2.0):
                raise PipelineError(f"modes.memory_s must list {self.K} memories of at least two samples")
            self.est.set_memory(mem)
            self.memory_s = mem
            self.faults.set_memory(mem)
            self.health.memory_s = mem
        if "publish_rate_hz" in params:
            rate = float(params["publish_rate_hz"])
            if not (rate > 0 and math.isfinite(rate)):
                raise PipelineError("publish_rate_hz must be > 0")
            self.publish_period = 1.0 / rate

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
        reports: list[Report] = []
        if t.size == 0:
            return reports
        c = self.counters
        c.samples_in += t.size
        s = self.settings
        # 1. stamps: drop non-finite, duplicate and out-of-order stamps (they never touch the grid)
        finite_t = np.isfinite(t)
        if self.t0 is None:
            if not finite_t.any():
                c.samples_dropped += t.size
                return reports
            self.t0 = float(t[np.argmax(finite_t)])
        start = -np.inf if self.t_last is None else self.t_last
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
        if idx.size == 0:
            return reports
        ta, ra, ua, ya = t[idx], r[idx], u[idx], y[idx]
        n = ta.size
        # 2. values: non-finite samples are given to the estimator as invalid (skipped, grid kept)
        fin = np.isfinite(ua) & np.isfinite(ya)
        if self.cfg.closed_loop:
            fin &= np.isfinite(ra)
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
        n_nonfin = int((~fin).sum())
        if n_nonfin:
            c.nonfinite += n_nonfin
            self.health.note("nonfinite", self._rel(float(ta[np.flatnonzero(~fin)[-1]])),
                             f"{c.nonfinite} non-finite sensor samples skipped")
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
            nrep = int(rep[a:b].sum())
            c.repeated += nrep
            self._win_rep += nrep
            self._advance(ta, ra, ua, ya, valid, a, b, feed=True, reports=reports)
        self.t_last = float(ta[-1])
        return reports

    def _on_break(self, why: str, kind: str | None, t_abs: float) -> None:
        """The sample grid is broken: re-prime the estimator (000 Algorithm 2 step 1) or restart the init buffer."""
        if kind is not None:
            self.health.note(kind, self._rel(t_abs), f"{why} (estimator re-primed)")
        if self.initialized:
            self.est.mark_gap()
        else:
            self._init_buf, self._init_n = [], 0

    def _advance(self, ta, ra, ua, ya, valid, a: int, b: int, *, feed: bool, reports: list[Report]) -> None:
        """Feed samples ``[a, b)`` (or only pass their time when ``feed`` is False), reporting on the way.

        A report at instant T is made once every accepted sample before T was processed; instants that
        fall inside a gap are collapsed into one report.
        """
        while a < b:
            t_next = self.t0 + self.next_publish
            j = a + int(np.searchsorted(ta[a:b], t_next, side="left"))
            if feed and not self.initialized:
                j = min(j, a + self.init_samples - self._init_n)
            if j > a:
                if feed:
                    self._consume(ra[a:j], ua[a:j], ya[a:j], valid[a:j], float(ta[j - 1]))
                a = j
                continue
            self._report(reports, self._rel(float(ta[a])))

    def _consume(self, r: np.ndarray, u: np.ndarray, y: np.ndarray, valid: np.ndarray, t_end: float) -> None:
        c = self.counters
        n = u.size
        c.samples_processed += n
        c.samples_skipped += int((~valid).sum())
        self._win_n += n
        if self.initialized:
            self.est.update(r, u, y, valid)
            return
        yv = np.where(valid, y, np.nan)   # invalid samples are NaN for the offline init (it skips them)
        self._init_buf.append((r.copy(), u.copy(), yv))
        self._init_n += n
        if self._init_n >= self.init_samples:
            rb, ub, yb = (np.concatenate([blk[q] for blk in self._init_buf]) for q in range(3))
            self._init_buf, self._init_n = [], 0
            self._initialize(rb, ub, yb, t_end)

    def _initialize(self, r: np.ndarray, u: np.ndarray, y: np.ndarray, t_end: float) -> None:
        """Offline initialization + filter priming on the buffered data (000 Algorithm 2 step 1)."""
        try:
            self.est.initialize(r, u, y)
        except Exception as exc:  # noqa: BLE001 - any failure of the offline init is a health incident
            self.counters.init_failures += 1
            self.health.note("reinitializing", self._rel(t_end), "initialization failed "
                             f"({type(exc).__name__}: {str(exc).splitlines()[0][:120] if str(exc) else ''}); "
                             "retrying on the next data")
            self.est = self._new_estimator()
            return
        self.counters.initializations += 1
        self.initialized = True
        modal = self._modal()
        if self.health.reference_modal is None and np.all(np.isfinite(modal[:, :3])):
            self.health.clear_reference(modal)

    # ------------------------------------------------------------------------------------------- reports
    def modal(self) -> np.ndarray:
        """Current (K, 6) estimate ``f_hz, zeta, gain`` and their std; NaN before the first initialization."""
        return self._modal()

    def _modal(self) -> np.ndarray:
        if not self.initialized:
            return np.full((self.K, 6), np.nan)
        return np.asarray(self.est.modal(), dtype=float).reshape(self.K, 6)

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
        est_health: dict[str, Any] = {}
        if self.initialized:
            est_health = dict(getattr(self.est, "health", {}) or {})
            if int(est_health.get("hold_remaining", 0) or 0) > 0:
                self.health.note("repriming", t_rep, "estimator filters re-priming after a data break")
            status = self.health.assess(t_rep, modal, est_health)
        else:
            self.health.note("initializing", t_rep, f"initializing: collecting {self.cfg.init_duration_s:g} s of "
                             "valid data for the offline initialization")
            status = self.health.status(t_rep)
        if self.initialized:
            upd = self.faults.update(t_rep, modal, hold=status.hold,
                                     suspect_since=status.values.get("advisory_since"))
            self.pending_opened += upd.opened
            self.pending_closed += upd.closed
        health = status.to_dict()
        if self.faults.anomaly_since is not None:
            health["reasons"].append(f"output anomaly since t={self.faults.anomaly_since:.1f} s (residual variance "
                                     "jump or projection storm): only a fault that began with it can be confirmed; "
                                     "later deviations wait until the estimates return to the baseline (or rebaseline)")
            health["level"] = max(int(health["level"]), int(Level.WARN))
            health["ok"] = False
        health["anomaly_since"] = self.faults.anomaly_since
        health.update(self.counters.to_dict())
        health["estimator"] = {k: _jsonable(v) for k, v in est_health.items()}
        health["stuck"] = self.stuck
        health["baseline_source"] = None if self.faults.baseline is None else self.faults.baseline.source
        b, bs = self.faults.baseline_arrays()
        rep = Report(time_s=t_rep, modal=modal, baseline=b, baseline_std=bs, flags=self.faults.flags,
                     levels=self.faults.levels, directions=self.faults.directions,
                     events_opened=self.pending_opened, events_closed=self.pending_closed, health=health,
                     phase=self.phase, estimating=self.initialized)
        reports.append(rep)
        self.last_report = rep
        self.pending_opened, self.pending_closed = [], []
        if self.initialized and "divergence" in status.values.get("new_issues", []):
            self._reinitialize(t_rep)

    def _reinitialize(self, t_rel: float) -> None:
        """Divergence: a fresh estimator initialized on the next data; baseline and events are kept."""
        self.est = self._new_estimator()
        self.initialized = False
        self._init_buf, self._init_n = [], 0
        self.counters.reinitializations += 1
        self.health.note("reinitializing", t_rel, "estimator diverged: re-initializing on new data")

    # ------------------------------------------------------------------------------------------- state
    def get_state(self) -> dict[str, Any]:
        """Estimator, baseline, fault tests, health and clock as JSON-serializable data.

        A partially filled initialization buffer is not saved (initialization restarts on new data);
        a restored running estimator re-primes on the first samples (they follow a gap).
        """
        est = None
        if self.initialized:
            est = {k: _jsonable(v) for k, v in self.est.get_state().items()}
        return {
            "version": STATE_VERSION, "K": self.K, "loop_rate_hz": self.rate, "model": self._model_record(),
            "estimator": est,
            "faults": self.faults.get_state(), "health": self.health.get_state(),
            "pipeline": {"t0": self.t0, "t_last": self.t_last, "next_publish": self.next_publish,
                         "counters": self.counters.to_dict(), "memory_s": self.memory_s.tolist(),
                         "stuck": self.stuck, "last_y": self.last_y, "run_len": self.run_len,
                         "run_start_t": self.run_start_t},
        }

    def _model_record(self) -> dict[str, Any]:
        """What a saved estimate is only valid for: rate, loop structure, controller, delay, mode structures."""
        c = getattr(self.cfg, "controller", None)
        return {"loop_rate_hz": self.rate, "closed_loop": bool(getattr(self.cfg, "closed_loop", False)),
                "controller_numerator": None if c is None else [float(v) for v in c.numerator],
                "controller_denominator": None if c is None else [float(v) for v in c.denominator],
                "input_delay_samples": int(getattr(self.cfg, "input_delay_samples", 0)),
                "integrators": [int(s.integrators) for s in self.cfg.structures],
                "orders": [[int(s.n), int(s.m)] for s in self.cfg.structures]}

    def _check_model_record(self, saved: Any) -> None:
        """Refuse (one line) a state saved under another model: another controller, delay, loop or structures."""
        if not isinstance(saved, Mapping):
            raise PipelineError("saved state does not record its controller, input delay and mode structures "
                                "(saved by an older version); not restored")
        mine = self._model_record()
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
            if int(state["K"]) != self.K or float(state["loop_rate_hz"]) != self.rate:
                raise PipelineError(f"saved state is for K={state['K']} at {state['loop_rate_hz']} Hz, the "
                                    f"configuration has K={self.K} at {self.rate} Hz")
            self._check_model_record(state.get("model"))
            p = state["pipeline"]
            self._new_run()
            mem = np.asarray(p["memory_s"], dtype=float)
            if mem.shape == (self.K,) and not np.array_equal(mem, self.memory_s):
                self.update_params({"modes.memory_s": mem.tolist()})
            if state["estimator"] is not None:
                self.est.set_state({k: np.asarray(v) for k, v in state["estimator"].items()})
                self.initialized = True
            self.faults.set_state(state["faults"])
            self.health.set_state(state["health"])
            self.t0 = None if p["t0"] is None else float(p["t0"])
            self.t_last = None if p["t_last"] is None else float(p["t_last"])
            self.next_publish = float(p["next_publish"])
            self.counters = _Counters(**p["counters"])
            self.stuck = bool(p["stuck"])
            self.last_y = None if p["last_y"] is None else float(p["last_y"])
            self.run_len, self.run_start_t = int(p["run_len"]), float(p["run_start_t"])
        except PipelineError:
            raise
        except (KeyError, TypeError, ValueError) as exc:
            raise PipelineError(f"saved state is incomplete or corrupt ({type(exc).__name__}: {exc})") from None


def _ffill(x: np.ndarray, first: float) -> np.ndarray:
    """Forward-fill NaNs (``first`` before the first finite value)."""
    idx = np.where(np.isnan(x), -1, np.arange(x.size))
    idx = np.maximum.accumulate(idx)
    out = np.where(idx >= 0, x[np.maximum(idx, 0)], first)
    return out


def _jsonable(v: Any) -> Any:
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, np.generic):
        return v.item()
    return v
