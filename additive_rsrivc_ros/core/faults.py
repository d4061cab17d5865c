"""Structural fault tests on the stream of modal estimates, kept apart from the estimator's health.

The recursion ([RA-SRIVC] Algorithm 2) publishes per mode ``[f_hz, zeta, gain]`` and their std (delta method on
``sigma^2 P_bar``). The steps below are cited by name (S1-S6) in this module's docstrings:

* S1 autocorrelation: with memory ``T`` the estimate is close to AR(1); ``tau_c = 2 T``, ``n_eff = W / (2 T)``.
* S2 baseline: mean over a healthy window, ``s_x = max(reported, empirical std)``, ``s_b = s_x / sqrt(n_eff)``.
* S3 test: two-sided CUSUM (Page 1954) on ``z = (x - b) / sqrt(s_x^2 + s_b^2)``, increments weighted ``dt / tau_c``,
  reference tuned to the minimum relevant change; the change time is the CUSUM's last zero.
* S4 decision: suspect when ``g > h`` and the deviation is relevant; fault after the persistence time; clear with
  hysteresis (``clear_fraction`` and the clear time).
* S5 health: data and estimator problems hold the tests (one mode's problem holds that mode only, :mod:`.decision`);
  advisory stress restricts confirmation for a bounded window.
* S6 joint confirmation (:mod:`.joint_check`): where a joint fit is needed, a deviation needs its support.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from enum import IntEnum
from typing import Any

import numpy as np

from .decision import Hold
from .estimator import EstimatorHealth
from .joint_check import JointVerdict, applicable_mask
from .model import SubmodelStructure
from .params import from_param, settings_as_params, settings_from_params
from .vocabulary import BASELINE_KEYS, EVENTS_HEADER, QUANTITIES


class Level(IntEnum):
    """diagnostic_msgs/DiagnosticStatus levels."""

    OK = 0
    WARN = 1
    ERROR = 2
    STALE = 3


class FaultConfigError(ValueError):
    """Fault settings or a given baseline that cannot be used (one-line message)."""


# ----------------------------------------------------------------------------------------------- settings
@dataclass(frozen=True)
class FaultSettings:
    """Thresholds of the fault logic: each field is filled from the ``faults.*`` row(s) it names (core/params.py,
    which holds their defaults, ranges and descriptions)."""

    enabled: bool = from_param("faults.enabled")
    settle_memory_lengths: float = from_param("faults.settle_memory_lengths")
    settle_max_memory_lengths: float = from_param("faults.settle_max_memory_lengths")
    baseline_duration_s: float = from_param("faults.baseline_duration_s")
    baseline_memory_lengths: float = from_param("faults.baseline_memory_lengths")
    # per quantity (BASELINE_KEYS), per mode; empty: learn the baseline
    baseline_value: tuple[tuple[float, ...], ...] = from_param(*(f"faults.baseline.{k}" for k in BASELINE_KEYS))
    baseline_std: tuple[tuple[float, ...], ...] = from_param(*(f"faults.baseline.{k}_std" for k in BASELINE_KEYS))
    min_change: tuple[float, float, float] = from_param(*(f"faults.min_change.{q}" for q in QUANTITIES))
    relevance_spread_factor: float = from_param("faults.min_change.spread_factor")
    cusum_reference_sigma: float = from_param("faults.cusum.reference_sigma")
    cusum_threshold: float = from_param("faults.cusum.threshold")
    cusum_false_alarm_interval_days: float = from_param("faults.cusum.false_alarm_interval_days")
    persistence_s: float = from_param("faults.persistence_s")
    persistence_memory_lengths: float = from_param("faults.persistence_memory_lengths")
    fast_memory_fraction: float = from_param("faults.fast.memory_fraction")
    fast_memory_lengths: float = from_param("faults.fast.memory_lengths")
    clear_s: float = from_param("faults.clear_s")
    clear_memory_lengths: float = from_param("faults.clear_memory_lengths")
    clear_fraction: float = from_param("faults.clear_fraction")
    health_holdoff_memory_lengths: float = from_param("faults.health.holdoff_memory_lengths")
    health_holdoff_min_s: float = from_param("faults.health.holdoff_min_s")
    health_max_condition: float = from_param("faults.health.max_condition")
    health_max_projection_fraction: float = from_param("faults.health.max_projection_fraction")
    health_residual_jump_ratio: float = from_param("faults.health.residual_jump_ratio")
    health_max_relative_std: float = from_param("faults.health.max_relative_std")
    health_max_parameter_ratio: float = from_param("faults.health.max_parameter_ratio")
    health_stuck_s: float = from_param("faults.health.stuck_s")
    health_stuck_min_samples: int = from_param("faults.health.stuck_min_samples")
    health_gap_tolerance: float = from_param("faults.health.gap_tolerance")
    health_repeated_output_is_missing: bool = from_param("faults.health.repeated_output_is_missing")
    health_max_repeated_fraction: float = from_param("faults.health.max_repeated_fraction")

    @classmethod
    def from_params(cls, p: Mapping[str, Any]) -> FaultSettings:
        """Build from flat ``faults.*`` parameters (missing names keep their defaults) and check them."""
        s = settings_from_params(cls, p)
        s.check()
        return s

    def check(self, n_modes: int | None = None) -> None:
        """Raise :class:`FaultConfigError` on inconsistent values (ranges are also in FAULT_PARAMS)."""
        if not all(v > 0 for v in self.min_change):
            raise FaultConfigError("faults.min_change.* must be > 0")
        if self.cusum_threshold < 0 or self.cusum_reference_sigma < 0 or not self.cusum_false_alarm_interval_days > 0:
            raise FaultConfigError("faults.cusum.threshold and faults.cusum.reference_sigma must be >= 0 and "
                                   "faults.cusum.false_alarm_interval_days > 0")
        if not 0.0 < self.clear_fraction < 1.0:
            raise FaultConfigError("faults.clear_fraction must be in (0, 1)")
        given = [len(v) for v in self.baseline_value]
        if any(given) and n_modes is not None:
            for key, n in zip(BASELINE_KEYS, given, strict=True):
                if n != n_modes:
                    raise FaultConfigError(f"faults.baseline.{key} has {n} entries but there are {n_modes} modes "
                                           "(give all three lists, or none to learn the baseline)")
            for key, v in zip(BASELINE_KEYS, self.baseline_std, strict=True):
                if len(v) not in (0, n_modes):
                    raise FaultConfigError(f"faults.baseline.{key}_std has {len(v)} entries, expected {n_modes} or 0")
                if any(not (x >= 0 and math.isfinite(x)) for x in v):
                    raise FaultConfigError(f"faults.baseline.{key}_std must be finite and >= 0")

    @property
    def has_given_baseline(self) -> bool:
        return any(len(v) for v in self.baseline_value)


# ----------------------------------------------------------------------------------------------- baseline
@dataclass
class Baseline:
    """Per-mode reference ``[f_hz, zeta, gain]`` (K, 3) with its uncertainty (S2)."""

    value: np.ndarray
    std: np.ndarray          # uncertainty of the baseline value (s_b)
    spread: np.ndarray       # typical fluctuation std of the estimate over the window (s_x)
    source: str = "learned"  # learned | given
    t_start: float = math.nan
    t_end: float = math.nan
    n_eff: np.ndarray | None = None
    learned_s: float = math.nan   # seconds of healthy estimates in the window (breaks excluded)
    trusted: bool = True          # False: learned over less than half a window (cut by a data problem or a change),
    #                               or its first and last thirds differ (a change spread over the window)
    note: str = ""                # why the window was cut short (empty for a complete window)

    def to_dict(self) -> dict[str, Any]:
        return {"value": self.value.tolist(), "std": self.std.tolist(), "spread": self.spread.tolist(),
                "source": self.source, "t_start": self.t_start, "t_end": self.t_end,
                "n_eff": None if self.n_eff is None else self.n_eff.tolist(), "learned_s": self.learned_s,
                "trusted": self.trusted, "note": self.note}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Baseline:
        return cls(np.asarray(d["value"], float), np.asarray(d["std"], float), np.asarray(d["spread"], float),
                   str(d["source"]), float(d["t_start"]), float(d["t_end"]),
                   None if d.get("n_eff") is None else np.asarray(d["n_eff"], float),
                   float(d.get("learned_s", math.nan)), bool(d.get("trusted", True)), str(d.get("note", "")))

    @classmethod
    def given(cls, settings: FaultSettings, n_modes: int) -> Baseline:
        """Baseline from ``faults.baseline.*`` lists; missing std lists mean an exact baseline."""
        settings.check(n_modes)
        value = np.array(settings.baseline_value, dtype=float).T
        std = np.zeros((n_modes, 3))
        for q, v in enumerate(settings.baseline_std):
            if len(v):
                std[:, q] = v
        if not np.all(np.isfinite(value)):
            raise FaultConfigError("faults.baseline.* values must be finite")
        return cls(value, std, std.copy(), "given")


def _baseline_from_sums(n: int, sx: np.ndarray, sxx: np.ndarray, sv: np.ndarray, duration_s: float,
                        memory_s: np.ndarray, t_start: float = math.nan, t_end: float = math.nan) -> Baseline:
    """Mean, fluctuation ``s_x = max(reported, empirical)`` and ``s_b = s_x / sqrt(n_eff)`` (S2) of ``n`` estimates
    from their sums, sums of squares and sums of reported variances over ``duration_s``."""
    mean = sx / n
    emp_var = np.maximum(sxx / n - mean * mean, 0.0) * (n / max(n - 1, 1))
    spread = np.sqrt(np.maximum(emp_var, sv / n))
    n_eff = np.clip(duration_s / (2.0 * np.asarray(memory_s, float)), 1.0, float(n))
    return Baseline(mean, spread / np.sqrt(n_eff)[:, None], spread, "learned", t_start, t_end, n_eff,
                    float(duration_s))


class BaselineLearner:
    """Accumulates the estimate over a healthy window and returns a :class:`Baseline` (S1, S2).

    A window may be paused (:meth:`pause`, a data problem): what was learned is kept and ``elapsed_s`` counts only
    the healthy stretches, so a window cut by a break resumes instead of starting again.
    """

    def __init__(self, n_modes: int) -> None:
        self.n_modes = n_modes
        self.reset(math.nan)

    def reset(self, t_start: float) -> None:
        self.t_start = t_start
        self.t_last = t_start
        self.n = 0
        self.elapsed_s = 0.0
        self.paused = False
        self.sum = np.zeros((self.n_modes, 3))
        self.sumsq = np.zeros((self.n_modes, 3))
        self.sum_var = np.zeros((self.n_modes, 3))
        # the same sums over the window's first and last thirds (``add(..., window_s)``), compared at its end
        self.thirds = np.zeros((2, 3, self.n_modes, 3))   # [first, last] x [sum, sum of squares, sum of variances]
        self.n_thirds = [0, 0]
        self.t_thirds = [0.0, math.nan]   # elapsed time of the first third's last, the last third's first estimate

    def pause(self) -> None:
        """A data problem: the time until the next :meth:`add` is not part of the window."""
        self.paused = True

    def add(self, t: float, modal: np.ndarray, window_s: float = math.inf) -> None:
        """One estimate; within the first or the last third of a ``window_s`` window it also counts there."""
        x, s = modal[:, :3], modal[:, 3:6]
        if self.n > 0 and not self.paused:
            self.elapsed_s += max(t - self.t_last, 0.0)
        self.paused = False
        self.n += 1
        var = np.where(np.isfinite(s), s * s, 0.0)   # a NaN std (flagged block): the empirical spread
        self.sum += x
        self.sumsq += x * x
        self.sum_var += var
        part = 0 if self.elapsed_s < window_s / 3.0 else (1 if self.elapsed_s >= 2.0 * window_s / 3.0 - 1e-9 else -1)
        if part >= 0:
            if part == 0:
                self.t_thirds[0] = self.elapsed_s
            elif self.n_thirds[1] == 0:
                self.t_thirds[1] = self.elapsed_s
            self.n_thirds[part] += 1
            self.thirds[part] += (x, x * x, var)
        self.t_last = t

    def outer_thirds(self, memory_s: np.ndarray) -> tuple[Baseline, Baseline] | None:
        """The window's first and last thirds as two :class:`Baseline` (mean, spread and S2 std each), or None while
        either holds fewer than two estimates. Thirds, not halves: a change spread over the whole window inflates
        each part's spread by a third of it, not half, so it stands out of the parts' fluctuation."""
        if min(self.n_thirds) < 2:
            return None
        durations = (self.t_thirds[0], self.elapsed_s - self.t_thirds[1])
        first, last = (_baseline_from_sums(self.n_thirds[k], self.thirds[k][0], self.thirds[k][1], self.thirds[k][2],
                                           durations[k], memory_s) for k in (0, 1))
        return first, last

    def finish(self, memory_s: np.ndarray, duration_s: float) -> Baseline:
        """Mean, fluctuation ``s_x = max(reported, empirical)`` and ``s_b = s_x / sqrt(n_eff)`` (S2)."""
        if self.n == 0:
            raise RuntimeError("baseline window holds no estimates")
        return _baseline_from_sums(self.n, self.sum, self.sumsq, self.sum_var, duration_s, memory_s, self.t_start,
                                   self.t_last)

    def to_dict(self) -> dict[str, Any]:
        return {"t_start": self.t_start, "t_last": self.t_last, "n": self.n, "sum": self.sum.tolist(),
                "sumsq": self.sumsq.tolist(), "sum_var": self.sum_var.tolist(), "elapsed_s": self.elapsed_s,
                "paused": self.paused, "thirds": self.thirds.tolist(), "n_thirds": list(self.n_thirds),
                "t_thirds": list(self.t_thirds)}

    def load(self, d: Mapping[str, Any]) -> None:
        self.t_start, self.t_last, self.n = float(d["t_start"]), float(d["t_last"]), int(d["n"])
        self.elapsed_s = float(d.get("elapsed_s", max(self.t_last - self.t_start, 0.0) if self.n else 0.0))
        self.paused = bool(d.get("paused", False))
        self.sum, self.sumsq = np.asarray(d["sum"], float), np.asarray(d["sumsq"], float)
        self.sum_var = np.asarray(d["sum_var"], float)
        # a state saved before the thirds were kept: none (no comparison of the thirds for this window)
        self.thirds = np.asarray(d["thirds"], float) if "thirds" in d else np.zeros((2, 3) + self.sum.shape)
        self.n_thirds = [int(v) for v in d.get("n_thirds", (0, 0))]
        self.t_thirds = [float(v) for v in d.get("t_thirds", (0.0, math.nan))]


def cusum_threshold(k: float, arl0: float) -> float:
    """CUSUM threshold ``h`` giving the in-control average run length ``arl0`` for reference ``k``.

    Siegmund's approximation for unit-variance Gaussian increments (S3):
    ``ARL0 = (exp(2 k b) - 2 k b - 1) / (2 k^2)`` with ``b = h + 1.166``; ``ARL0 = b^2`` as ``k -> 0``.
    """
    if not (arl0 > 1.0 and math.isfinite(arl0)):
        raise ValueError(f"arl0 must be a finite number > 1, got {arl0}")
    if k < 1e-3:
        return max(math.sqrt(arl0) - 1.166, 0.0)
    c = 2.0 * k * k * arl0
    b = math.log(c + 1.0) / (2.0 * k)
    for _ in range(50):                  # fixed point of exp(2kb) = c + 2kb + 1 (monotone, converges fast)
        b_new = math.log(c + 2.0 * k * b + 1.0) / (2.0 * k)
        if abs(b_new - b) < 1e-12 * max(1.0, b):
            b = b_new
            break
        b = b_new
    return max(b - 1.166, 0.0)


# ----------------------------------------------------------------------------------------------- events
@dataclass
class FaultEvent:
    """One structural fault episode; fields map onto events.csv (docs/INTERFACE.md)."""

    mode: int                  # 1-based, as in the diagnostics status name "mode <i>"
    quantity: str              # natural_frequency | damping | gain
    direction: str             # up | down
    onset_time_s: float        # estimated change time (S3), s since the first sample
    alarm_time_s: float        # time the fault was confirmed
    baseline: float
    value: float               # latest estimate while the fault was present
    clear_time_s: float | None = None
    z: float = math.nan        # normalized deviation at confirmation

    @property
    def is_open(self) -> bool:
        return self.clear_time_s is None

    def csv_row(self) -> dict[str, Any]:
        """The events.csv columns (``vocabulary.EVENTS_HEADER``); an empty clear time while open
        (``vocabulary.events_csv_cells`` writes them)."""
        row = {k: getattr(self, k) for k in EVENTS_HEADER}
        if self.clear_time_s is None:
            row["clear_time_s"] = ""
        return row

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)



@dataclass
class SequentialTest:
    """Two-sided CUSUM with relevance gate, persistence and clear hysteresis for one mode/quantity (S3, S4)."""

    mode: int
    quantity: str
    g_up: float = 0.0
    g_down: float = 0.0
    zero_up_t: float = math.nan
    zero_down_t: float = math.nan
    small_up_t: float = math.nan      # last time the deviation was below clear_fraction * relevant change
    small_down_t: float = math.nan
    gate_up_since: float = math.nan   # start of the current stretch with deviation >= relevant change
    gate_down_since: float = math.nan
    state: str = "ok"                 # ok | suspect | fault
    direction: int = 0
    since: float = math.nan           # suspect start / clear-streak start
    event: FaultEvent | None = None
    last_z: float = 0.0
    h: float = math.nan               # threshold used at the last step
    confirm_before: float = math.inf  # a relevant deviation starting later is not confirmed (advisory health)
    confirm_by_onset: bool = False    # compare the deviation's onset (not its relevance crossing) with it
    by_joint: bool = False            # the open event was confirmed by the joint check (S6), which also clears it
    joint_miss: int = 0               # consecutive joint checks that no longer support that event

    @property
    def level(self) -> Level:
        return {"ok": Level.OK, "suspect": Level.WARN, "fault": Level.ERROR}[self.state]

    @property
    def flag(self) -> bool:
        return self.state == "fault"

    @property
    def direction_name(self) -> str:
        return {1: "up", -1: "down"}.get(self.direction, "")

    def reset(self, t: float) -> None:
        """Forget the accumulated evidence (after a clear, a rebaseline or a hold)."""
        self.g_up = self.g_down = 0.0
        self.zero_up_t = self.zero_down_t = self.small_up_t = self.small_down_t = t
        self.gate_up_since = self.gate_down_since = math.nan
        if self.state != "fault":
            self.state, self.direction, self.since = "ok", 0, math.nan
            self.by_joint, self.joint_miss = False, 0

    def open_joint(self, t: float, onset: float, direction: int, baseline: float, value: float, z: float,
                   ) -> FaultEvent:
        """Confirm a change the joint check supports (S6): the event carries the joint fit's value."""
        self.state, self.direction, self.since = "fault", direction, math.nan
        self.by_joint, self.joint_miss = True, 0
        self.event = FaultEvent(self.mode, self.quantity, self.direction_name, onset, t, baseline, value, None, z)
        return self.event

    def step(self, t: float, w: float, x: float, sigma_d: float, b: float, rho: float, k: float, h: float,
             clear_fraction: float, persist_s: float, clear_s: float, *, arl0: float = 1e6,
             ) -> tuple[FaultEvent | None, FaultEvent | None]:
        """Advance the test by one estimate ``x`` (S3, S4); returns (opened event, closed event).

        ``h <= 0`` selects the threshold from the in-control run length ``arl0`` (:func:`cusum_threshold`).
        """
        dev = x - b
        rel = dev / abs(b)
        z = dev / sigma_d
        self.last_z = z
        k_eff = max(k, 0.5 * rho * abs(b) / sigma_d)   # reference of the CUSUM tuned to the relevant change
        if h <= 0.0:   # floor: at least one independent estimate's worth of excess over k
            h = max(cusum_threshold(k_eff, arl0), 1.0)
        self.h = h
        cap = 2.0 * h
        self.g_up = min(cap, max(0.0, self.g_up + w * (z - k_eff)))
        self.g_down = min(cap, max(0.0, self.g_down + w * (-z - k_eff)))
        if self.g_up == 0.0:
            self.zero_up_t = t
        if self.g_down == 0.0:
            self.zero_down_t = t
        if rel < clear_fraction * rho:
            self.small_up_t = t
        if rel > -clear_fraction * rho:
            self.small_down_t = t
        self.gate_up_since = (t if math.isnan(self.gate_up_since) else self.gate_up_since) if rel >= rho else math.nan
        self.gate_down_since = ((t if math.isnan(self.gate_down_since) else self.gate_down_since) if rel <= -rho
                                else math.nan)
        opened = closed = None
        if self.state == "fault":
            assert self.event is not None      # the fault state always carries its open event
            d = self.direction
            present = d * rel >= clear_fraction * rho and d * z >= k
            if present:
                self.since = math.nan
                self.event.value = x
            else:
                if math.isnan(self.since):
                    self.since = t
                if t - self.since >= clear_s:
                    self.event.clear_time_s = self.since
                    closed = self.event
                    self.event, self.state, self.direction, self.since = None, "ok", 0, math.nan
                    self.reset(t)
            return opened, closed
        cand = 0
        if self.g_up > h and rel >= rho:
            cand = 1
        elif self.g_down > h and rel <= -rho:
            cand = -1
        if cand == 0:
            self.state, self.direction, self.since = "ok", 0, math.nan
            return opened, closed
        if self.state != "suspect" or cand != self.direction:
            self.state, self.direction, self.since = "suspect", cand, t
        gate_since = self.gate_up_since if cand > 0 else self.gate_down_since
        zero_t = self.zero_up_t if cand > 0 else self.zero_down_t
        small_t = self.small_up_t if cand > 0 else self.small_down_t
        onset = np.nanmax([zero_t, small_t, -np.inf])
        onset = min(float(onset), self.since) if math.isfinite(onset) else self.since
        began = min(onset, gate_since) if self.confirm_by_onset else gate_since
        if t - gate_since >= persist_s and began <= self.confirm_before:
            self.event = FaultEvent(self.mode, self.quantity, self.direction_name, onset, t, b, x, None, z)
            self.state, self.since = "fault", math.nan
            opened = self.event
        return opened, closed

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["event"] = None if self.event is None else self.event.to_dict()
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> SequentialTest:
        d = dict(d)
        ev = d.pop("event", None)
        out = cls(**d)
        out.event = None if ev is None else FaultEvent(**ev)
        return out


# ----------------------------------------------------------------------------------------------- monitor
@dataclass
class FaultUpdate:
    """What one :meth:`FaultMonitor.update` changed."""

    opened: list[FaultEvent] = field(default_factory=list)
    closed: list[FaultEvent] = field(default_factory=list)
    baseline_ready: bool = False


FAST_DECAY_TIMES = 3.0
"""S7: a shortened memory keeps at least this many decay times of the mode (the estimator's own stable range)."""


class FaultMonitor:
    """Baseline + per mode/quantity sequential tests on the modal estimate stream (S1-S4).

    ``update(t, modal, hold=...)`` is called at the publish rate with the estimator's ``modal()``
    array (K, 6). Phases: ``waiting`` (no estimate yet) -> ``settling`` (settle_memory_lengths x the
    longest memory) -> ``learning`` (baseline window) -> ``monitoring``; with a given baseline the
    learning phase is skipped. ``hold=True`` (bad health or a data problem, S5) freezes the tests; it never
    resets a baseline: a window in progress is paused and resumes once the estimate has re-settled, unless the
    estimate then differs from what was learned before by a relevant change (S4 relevance), in which case the
    partial window becomes the baseline and the change is monitored against it (untrusted below half a window).
    The same guard runs on every estimate of the window, so a plant change never becomes the baseline silently.
    """

    def __init__(self, memory_s: Sequence[float] | np.ndarray, settings: FaultSettings | None = None, *,
                 structures: Sequence[SubmodelStructure] | None = None) -> None:
        self.memory_s = np.asarray(memory_s, dtype=float)
        if self.memory_s.ndim != 1 or self.memory_s.size == 0 or not np.all(self.memory_s > 0):
            raise FaultConfigError("memory_s must list one positive memory length per mode")
        self.K = self.memory_s.size
        self.structures = list(structures) if structures is not None else [SubmodelStructure()] * self.K
        if len(self.structures) != self.K:
            raise FaultConfigError(f"{len(self.structures)} structures for {self.K} modes")
        self.settings = settings or FaultSettings()
        self.settings.check(self.K)
        self.tests = [[SequentialTest(i + 1, q) for q in QUANTITIES] for i in range(self.K)]
        self.learner = BaselineLearner(self.K)
        self.baseline: Baseline | None = Baseline.given(self.settings, self.K) \
            if self.settings.has_given_baseline else None
        self.phase = "waiting"
        self.t_phase = math.nan
        self.t_last = math.nan
        self.held = False
        self.events: list[FaultEvent] = []   # every event ever opened (open ones are also in tests)
        self.last_modal = np.full((self.K, 6), np.nan)
        self.history: deque[tuple[float, np.ndarray]] = deque()
        self.settle_forced = False
        self.anomaly_since: float | None = None   # start of the advisory stress episode (S5), see update()
        self.break_t = math.nan                   # first data problem that paused the current baseline window
        # S6, per mode: the baseline's joint fit found a quantity of that mode not identifiable; only such a mode's
        # deviations need the joint check's support (a weakly excited mode does not make its neighbours wait)
        self.joint_armed_modes = np.zeros(self.K, dtype=bool)
        self.joint: JointVerdict | None = None    # the latest joint check (S6)
        self.joint_reference: JointVerdict | None = None   # the joint fit of the end of the baseline window (S6)
        self.joint_streak = np.zeros((self.K, 3), dtype=int)   # signed run of consecutive supporting checks
        self.joint_several_modes_t = math.nan   # last stressed joint check that moved several modes at once
        self.several_modes = False              # under stress, several modes deviate at once (see update)
        # S7, per mode: a detected change shortens the mode's memory until fast_until (variable forgetting); one
        # shortening per change: re-armed once every CUSUM of the mode is back at rest
        self.fast_until = np.full(self.K, -math.inf)
        self.fast_spent = np.zeros(self.K, dtype=bool)

    # -- configuration
    @classmethod
    def from_config(cls, cfg: Any) -> FaultMonitor:
        """From a :class:`..config.MonitorConfig` (memories, structures and ``faults.*`` parameters)."""
        return cls([m.memory_s for m in cfg.modes], FaultSettings.from_params(cfg.params),
                   structures=cfg.structures)

    def update_settings(self, params: Mapping[str, Any]) -> None:
        """Apply changed ``faults.*`` thresholds at runtime (node parameter callback); state is kept.

        ``params`` may hold only the changed names; a given baseline is applied when its lists change.
        """
        merged = settings_as_params(self.settings)
        merged.update({k: v for k, v in params.items() if k.startswith("faults.")})
        new = FaultSettings.from_params(merged)
        new.check(self.K)
        old = self.settings
        self.settings = new
        if new.baseline_value != old.baseline_value or new.baseline_std != old.baseline_std:
            if new.has_given_baseline:
                self.baseline = Baseline.given(new, self.K)
                if self.phase == "learning":
                    self.phase = "monitoring"
            elif old.has_given_baseline:
                self.rebaseline(self.t_last)

    def set_memory(self, memory_s: Sequence[float] | np.ndarray) -> None:
        """Follow a runtime memory change (time constants of S1 and of the persistence/clear times)."""
        m = np.asarray(memory_s, dtype=float)
        if m.shape != self.memory_s.shape or not np.all(m > 0):
            raise FaultConfigError(f"memory_s must list {self.K} positive values")
        self.memory_s = m

    # -- derived times
    @property
    def settle_s(self) -> float:
        return self.settings.settle_memory_lengths * float(self.memory_s.max())

    @property
    def baseline_window_s(self) -> float:
        s = self.settings
        return s.baseline_duration_s if s.baseline_duration_s > 0 else s.baseline_memory_lengths * float(
            self.memory_s.max())

    def persistence_s(self, i: int) -> float:
        s = self.settings
        return max(s.persistence_s, s.persistence_memory_lengths * self.effective_memory_s(i))

    def memory_scale(self) -> np.ndarray:
        """(K,) factor on each mode's configured memory the estimator should use now (S7: 1, or
        ``faults.fast.memory_fraction`` while a detected change is being tracked, but never below
        ``FAST_DECAY_TIMES`` decay times ``1/(zeta omega)`` of the mode's baseline: a memory shorter than the mode's
        own transient makes the estimate and its prefilters oscillate, see ``set_filter_policy`` of the estimator)."""
        fast = self.t_last < self.fast_until
        if not fast.any():
            return np.ones(self.K)
        floor = np.zeros(self.K)
        if self.baseline is not None:
            with np.errstate(divide="ignore", invalid="ignore"):
                decay = 1.0 / (self.baseline.value[:, 1] * 2.0 * math.pi * self.baseline.value[:, 0])
            second_order = np.array([s.n == 2 for s in self.structures])
            floor = np.where(second_order & np.isfinite(decay), FAST_DECAY_TIMES * decay / self.memory_s, 0.0)
        scale = np.minimum(1.0, np.maximum(self.settings.fast_memory_fraction, floor))
        return np.where(fast, scale, 1.0)

    def effective_memory_s(self, i: int) -> float:
        """Mode ``i``'s memory as the estimator uses it now (S7): its estimates decorrelate, and a transient in them
        fades, within it."""
        return float(self.memory_s[i]) * float(self.memory_scale()[i])

    def clear_time_s(self, i: int) -> float:
        s = self.settings
        return max(s.clear_s, s.clear_memory_lengths * float(self.memory_s[i]))

    def arl0_samples(self, i: int) -> float:
        """Target in-control run length of one CUSUM side in independent estimates (S1: one per 2 T_i)."""
        return self.settings.cusum_false_alarm_interval_days * 86400.0 / (2.0 * float(self.memory_s[i]))

    def applicable(self, i: int, q: int) -> bool:
        """Frequency and damping are tested only for second-order modes (a rigid body has only a gain)."""
        return q == 2 or self.structures[i].n == 2

    # -- main step
    def rebaseline(self, t: float) -> list[FaultEvent]:
        """Forget the baseline and learn a new one from now on; open events are closed at ``t``."""
        closed = []
        for row in self.tests:
            for test in row:
                if test.event is not None:
                    test.event.clear_time_s = t
                    closed.append(test.event)
                test.event, test.state, test.direction, test.since = None, "ok", 0, math.nan
                test.reset(t)
        self.baseline = None
        self.anomaly_since = None
        self.break_t = math.nan
        self.joint_armed_modes[:] = False
        self.joint, self.joint_reference = None, None
        self.joint_streak[:] = 0
        self.fast_until[:], self.fast_spent[:] = -math.inf, False
        if self.phase in ("learning", "monitoring"):
            self.phase, self.t_phase = "learning", t
            self.learner.reset(t)
        return closed

    def update(self, t: float, modal: np.ndarray, *, hold: bool = False,
               suspect_since: float | None = None, mode_hold: Sequence[bool] | np.ndarray | None = None,
               ) -> FaultUpdate:
        """Process one modal estimate (K, 6) at time ``t`` (s); see the class docstring.

        ``suspect_since`` (S5, advisory health issues such as a residual-variance jump): the estimator has
        been under stress since that time; a fault is then confirmed only if its deviation began no later than
        two memory lengths after it (five for a natural frequency, measured from the deviation's onset: its
        estimate can stay in a broadened fit for a while before it travels) -- the stress is explained by that
        structural change -- and it is the mode's leading deviation: the natural frequency when it is relevant
        (a frequency shift makes damping and gain swing while the estimate re-converges, not the converse),
        else the most significant (largest ``|z|``); other tests stay at WARN. This isolation is bounded
        (:meth:`restricted_until`): after it every persistent deviation is judged against the baseline again. At all
        times damping and gain are confirmed only once they and the mode's frequency hold still (:meth:`_moving`).

        ``mode_hold`` (K,) bool: holds scoped to single modes (:mod:`.decision`): a held mode's tests are reset and
        do not step (an open event stays open); the other modes are judged on their own.
        """
        out = FaultUpdate()
        modal = np.asarray(modal, dtype=float)
        if modal.shape != (self.K, 6):
            raise ValueError(f"modal estimate must have shape ({self.K}, 6), got {modal.shape}")
        dt = 0.0 if math.isnan(self.t_last) else max(t - self.t_last, 0.0)
        self.t_last = t
        self.last_modal = modal.copy()
        finite = bool(np.all(np.isfinite(modal[:, :3])))
        self.held = hold or not finite
        if self._baseline_phases(t, modal, suspect_since, out):
            return out
        if not self.settings.enabled or self.baseline is None:
            return out
        s = self.settings
        base = self.baseline
        sx = np.fmax(modal[:, 3:6], base.spread)     # fmax: a NaN std (flagged covariance) falls back to the spread
        sigma = np.maximum(np.sqrt(sx * sx + base.std ** 2), 1e-9 * np.abs(base.value))
        with np.errstate(divide="ignore", invalid="ignore"):
            # relevant change: the user's minimum, and well above the estimate's own healthy fluctuation (a mode
            # that wanders by 1 % with the operating point must not alarm on a 2 % excursion)
            rho = np.maximum(np.asarray(s.min_change)[None, :],
                             s.relevance_spread_factor * base.spread / np.abs(base.value))
            rho = np.where(np.isfinite(rho), rho, np.asarray(s.min_change)[None, :])
            dev = modal[:, :3] - base.value
            relevant = np.abs(dev) >= rho * np.abs(base.value)
            score = np.where(relevant, np.abs(dev) / sigma, -1.0)
        score = np.where(np.isfinite(score), score, -1.0)
        for i in range(self.K):
            for q in range(3):
                if not self.applicable(i, q):
                    score[i, q] = -1.0
        # S5: an advisory stress episode restricts confirmation for a bounded window from its start (isolation,
        # _confirm_before); the window never waits for the estimates to return: once it has passed, every persistent
        # deviation is judged against the baseline. The episode ends when the advisory issue has lapsed.
        if suspect_since is not None and suspect_since < self.t_phase:
            suspect_since = None   # a stress older than the monitoring phase: deviations are judged afresh from it
        if suspect_since is not None:
            self.anomaly_since = suspect_since if self.anomaly_since is None else min(self.anomaly_since,
                                                                                         suspect_since)
        elif self.anomaly_since is not None and t >= max(self.restricted_until(i) or t for i in range(self.K)):
            self.anomaly_since = None
        stress_since = self.anomaly_since
        held_mode = np.zeros(self.K, dtype=bool) if mode_hold is None else np.asarray(mode_hold, dtype=bool)
        # under stress, relevant deviations of several modes at once (and no fault of this episode that explains
        # them) are no single structural change (a sensor bias or drift refits every mode): the recursion confirms
        # none of them; only the joint check, mode by mode, can
        deviating = np.any(relevant & (score >= 0), axis=1) & ~held_mode
        self.several_modes = bool(stress_since is not None and int(deviating.sum()) >= 2 and not any(
            e.alarm_time_s >= stress_since for e in self.open_events))
        lead = np.argmax(score, axis=1)   # the most significant of the mode's relevant deviations
        moving = self._moving(t, modal, rho)
        arriving = self._moving(t, modal, rho, lookback=0.5)
        for i in range(self.K):
            # a natural-frequency shift explains the damping and gain swings of the estimate while it re-converges
            # (a lightly damped mode fitted at the old frequency looks broader); the converse does not hold
            if self.applicable(i, 0) and score[i, 0] >= 0:
                lead[i] = 0
            faulted = [q for q in range(3) if self.tests[i][q].state == "fault"]
            if faulted:                   # ... and a confirmed fault of the mode explains the rest
                lead[i] = faulted[0]
        for i in range(self.K):
            w = min(1.0, dt / (2.0 * self.effective_memory_s(i)))   # S1: weight per independent sample
            if held_mode[i]:
                for test in self.tests[i]:
                    test.reset(t)       # evidence gathered under the hold is not evidence; an open event stays
                continue
            self._track_change(i, t)
            for q in range(3):
                if not self.applicable(i, q):
                    continue
                b = float(base.value[i, q])
                if b == 0.0 or not math.isfinite(b):
                    continue
                sigma_d = float(sigma[i, q])
                test = self.tests[i][q]
                if test.by_joint:
                    continue        # S6: the joint check holds and clears its own events
                test.confirm_by_onset = q == 0
                test.confirm_before = -math.inf if self.several_modes else self._confirm_before(
                    i, q, bool(moving[i, 0] or arriving[i, q]), stress_since, int(lead[i]))
                opened, closed = test.step(
                    t, w, float(modal[i, q]), sigma_d, b, float(rho[i, q]), s.cusum_reference_sigma,
                    s.cusum_threshold, s.clear_fraction, self.persistence_s(i), self.clear_time_s(i),
                    arl0=self.arl0_samples(i))
                if opened is not None:
                    out.opened.append(opened)
                    self.events.append(opened)
                if closed is not None:
                    out.closed.append(closed)
        return out

    def _track_change(self, i: int, t: float) -> None:
        """S7, variable forgetting: when a CUSUM of mode ``i`` has crossed its threshold (a statistically sure
        change, about half the relevant size) and the mode has no open event, shorten the mode's memory to
        ``faults.fast.memory_fraction`` for ``faults.fast.memory_lengths`` memory lengths (a known remedy of
        recursive identification, [RA-SRIVC] §4's forgetting made time-varying): the estimate reaches the changed
        plant in a fraction of a memory instead of several. The evidence of the tests is judged with the shortened
        memory meanwhile."""
        tests = self.tests[i]
        if self.fast_spent[i]:
            if t >= self.fast_until[i] and all(tst.g_up == 0.0 and tst.g_down == 0.0 for tst in tests):
                self.fast_spent[i] = False          # the change is over (or was none): the next one may shorten
            return
        if self.settings.fast_memory_fraction >= 1.0:
            return
        if any(tst.state == "fault" for tst in tests):
            return
        if any(max(tst.g_up, tst.g_down) > tst.h for tst in tests if math.isfinite(tst.h)):
            self.fast_until[i] = t + self.settings.fast_memory_lengths * float(self.memory_s[i])
            self.fast_spent[i] = True

    def stress_window_s(self, i: int, q: int) -> float:
        """Length of the isolation window after a stress began (S5): a lightly damped mode's frequency estimate can
        stay in the broadened fit for a few memory lengths before it travels (and no sensor bias moves it)."""
        return (5.0 if q == 0 else 2.0) * float(self.memory_s[i])

    def restricted_until(self, i: int) -> float | None:
        """End of mode ``i``'s isolation window under the current stress episode (None without one)."""
        if self.anomaly_since is None:
            return None
        return self.anomaly_since + max(self.stress_window_s(i, q) for q in range(3))

    def _confirm_before(self, i: int, q: int, travelling: bool, stress_since: float | None, lead: int) -> float:
        """Latest onset of a deviation of (mode ``i``, quantity ``q``) that may still be confirmed (S4-S6)."""
        if self.joint_needed(i, q) and self.joint_streak[i, q] == 0:
            return -math.inf        # S6: the data do not support this deviation jointly
        if q > 0 and travelling:
            # damping and gain are confirmed once they, and the mode's frequency, hold still: while the
            # frequency travels they swing with it, and a swing is not a new level
            return -math.inf
        if stress_since is None:
            return math.inf
        if q != lead and any(tst.state == "fault" for tst in self.tests[i]):
            # while the stress lasts (a bounded advisory hold-off), the mode's confirmed fault explains the swings of
            # its other quantities as the estimate re-converges
            return -math.inf
        if self.t_last >= stress_since + self.stress_window_s(i, q):
            return math.inf         # the isolation window has passed: judged against the baseline
        if q == lead:
            return stress_since + self.stress_window_s(i, q)   # the deviation must begin with the stress
        return -math.inf            # isolation under stress: only the mode's dominant deviation can be the fault

    def _baseline_phases(self, t: float, modal: np.ndarray, suspect_since: float | None, out: FaultUpdate) -> bool:
        """Hold, settling and baseline learning (S2, S5); True when this update ends here (no test step)."""
        if self.phase == "waiting":
            self.phase, self.t_phase = "settling", t
        if self.held:
            if self.phase == "learning":
                # a data problem (gap, re-priming, sensor, re-initialization) during the window: keep what was
                # learned, pause, and resume once the estimate has re-settled (see _resume_window)
                self.learner.pause()
                self.phase, self.t_phase = "settling", t - self.settle_s
                if math.isnan(self.break_t):
                    self.break_t = t
            for row in self.tests:
                for test in row:
                    test.reset(t)
            return True
        self._remember(t, modal)
        if self.phase == "settling":
            if t - self.t_phase < self.settle_s:
                return True
            forced = t - self.t_phase >= self.settings.settle_max_memory_lengths * float(self.memory_s.max())
            if not (forced or self.converged(t, modal)):
                return True
            self.settle_forced = forced and not self.converged(t, modal)
            if self.baseline is not None:
                self._start_monitoring(t, t, out)
            elif self.learner.n > 0:
                if self._resume_window(t, modal, out):
                    return True
            else:
                self.phase, self.t_phase = "learning", t
                self.learner.reset(t)
        if self.phase == "learning" and suspect_since is not None and suspect_since >= self.t_phase:
            # the estimator came under stress during the window (e.g. a residual-variance jump: the plant may have
            # just changed): the window must not run into the transient. Keep what was learned before (the change
            # is then monitored against it; untrusted below half a window), never let the new state become the
            # baseline; with nothing learned yet, start again once the estimate has settled.
            if self.learner.n > 0:
                self._keep_partial(t, suspect_since, f"estimator stress (residual jump or projections) at "
                                   f"t={suspect_since:.1f} s", out)   # the stress belongs to the monitoring
            else:
                self.phase, self.t_phase = "settling", t
                return True
        if self.phase == "learning":
            change = self._window_change(modal)
            if change is not None:
                self._keep_partial(t, t, f"the estimate moved during the window ({change})", out)
                return True
            self.learner.add(t, modal, window_s=self.baseline_window_s)
            if self.learner.elapsed_s >= self.baseline_window_s - 1e-9:
                self.baseline = self.learner.finish(self.memory_s, self.learner.elapsed_s)
                moved = self._thirds_change()
                if moved is not None:
                    # a change spread over the window (a slow fault, a still converging estimate) passes the check
                    # of each estimate against the partial, whose spread grows with it: never a trusted baseline
                    self.baseline.trusted = False
                    self.baseline.note = (f"the estimate moved during the {self.learner.elapsed_s:.1f} s baseline "
                                          f"window ({moved} from its first third to its last); baseline untrusted")
                self.break_t = math.nan
                self._start_monitoring(t, t, out)
            return True
        return False

    def _window_change(self, modal: np.ndarray) -> str | None:
        """A relevant and significant deviation of ``modal`` from the partial baseline learned so far (S3 relevance
        ``rho`` and ``z >= 3`` with the partial's spread), as ``"mode i quantity +x.x %"``; None if there is none or
        too little was learned (fewer than two estimates)."""
        if self.learner.n < 2:
            return None
        part = self.learner.finish(self.memory_s, self.learner.elapsed_s)
        sx = np.fmax(modal[:, 3:6], part.spread)
        return self._largest_change(modal[:, :3], part.value, np.sqrt(sx * sx + part.std ** 2), part.spread)

    def _largest_change(self, value: np.ndarray, ref: np.ndarray, sigma: np.ndarray,
                        spread: np.ndarray) -> str | None:
        """The largest relevant (S3 ``rho`` with the fluctuation ``spread``) and significant (``|dev| >= 3 sigma``)
        relative change of ``value`` from ``ref`` (K, 3) over the applicable quantities, as ``"mode i quantity
        +x.x %"``; None if there is none."""
        s = self.settings
        with np.errstate(divide="ignore", invalid="ignore"):
            rho = np.maximum(np.asarray(s.min_change)[None, :], s.relevance_spread_factor * spread / np.abs(ref))
            dev = value - ref
            rel = dev / np.abs(ref)
            hit = (np.abs(rel) >= rho) & (np.abs(dev) >= 3.0 * sigma)
        best, text = -1.0, None
        for i in range(self.K):
            for q in range(3):
                if self.applicable(i, q) and bool(hit[i, q]) and abs(rel[i, q]) > best:
                    best, text = abs(rel[i, q]), f"mode {i + 1} {QUANTITIES[q]} {100.0 * rel[i, q]:+.1f} %"
        return text

    def _thirds_change(self) -> str | None:
        """A relevant and significant difference between the means of the window's first and last thirds (S3
        relevance ``rho`` with the larger third's spread, ``z >= 3`` with each third's S2 std), as ``"mode i quantity
        +x.x %"``."""
        thirds = self.learner.outer_thirds(self.memory_s)
        if thirds is None:
            return None
        first, last = thirds
        return self._largest_change(last.value, first.value, np.sqrt(first.std ** 2 + last.std ** 2),
                                    np.fmax(first.spread, last.spread))

    def _resume_window(self, t: float, modal: np.ndarray, out: FaultUpdate) -> bool:
        """The estimate re-settled after a data problem cut the baseline window: continue learning if it still
        matches what was learned before, else keep the partial baseline (the change is a fault candidate, never
        absorbed into the baseline). Returns True when monitoring started."""
        change = self._window_change(modal)
        if change is not None:
            since = self.break_t if math.isfinite(self.break_t) else t
            self._keep_partial(t, since, f"the estimate after the data break at t={since:.1f} s differs from it "
                               f"({change})", out)
            return True
        self.phase, self.t_phase = "learning", t
        return False

    def _keep_partial(self, t: float, t_phase: float, why: str, out: FaultUpdate) -> None:
        """End the window early: the baseline is what was learned so far; untrusted below half a window."""
        elapsed = self.learner.elapsed_s
        base = self.learner.finish(self.memory_s, elapsed)
        base.trusted = elapsed >= 0.5 * self.baseline_window_s
        base.note = (f"baseline learned over {elapsed:.1f} s of the {self.baseline_window_s:.1f} s window: {why}"
                     + ("" if base.trusted else "; baseline untrusted"))
        self.baseline = base
        self.break_t = math.nan
        self._start_monitoring(t, min(t_phase, t), out)

    @property
    def baseline_trusted(self) -> bool:
        """False while monitoring against a baseline learned over less than half a window."""
        return self.baseline is None or self.baseline.trusted

    def _start_monitoring(self, t: float, t_phase: float, out: FaultUpdate) -> None:
        """Enter the monitoring phase (its start ``t_phase``) with fresh tests."""
        self.phase, self.t_phase = "monitoring", t_phase
        out.baseline_ready = True
        for row in self.tests:
            for test in row:
                test.reset(t)

    def _moving(self, t: float, modal: np.ndarray, rho: np.ndarray, lookback: float = 1.0) -> np.ndarray:
        """(K, 3) bool: over the last ``lookback`` memory lengths (as the estimator uses them now, S7) the estimate
        moved by more than three of its std and a tenth of the relevant change, i.e. it is still travelling."""
        out = np.zeros((self.K, 3), dtype=bool)
        for i in range(self.K):
            then = self._estimate_ago(t, lookback * self.effective_memory_s(i))
            if then is None:
                continue
            for q in range(3):
                if not self.applicable(i, q):
                    continue
                step = abs(modal[i, q] - then[i, q])
                tol = max(3.0 * float(modal[i, 3 + q]), 0.1 * float(rho[i, q]) * abs(float(modal[i, q])))
                out[i, q] = bool(math.isfinite(step) and step > tol)
        return out

    def _estimate_ago(self, t: float, lag_s: float) -> np.ndarray | None:
        """The latest remembered estimate at least ``lag_s`` before ``t`` (None if the history is shorter)."""
        for tp, m in reversed(self.history):
            if tp <= t - lag_s:
                return m
        return None

    def _remember(self, t: float, modal: np.ndarray) -> None:
        self.history.append((t, modal.copy()))
        horizon = 1.5 * float(self.memory_s.max())
        while len(self.history) > 2 and t - self.history[1][0] >= horizon:
            self.history.popleft()

    def converged(self, t: float, modal: np.ndarray) -> bool:
        """The estimate has settled: over the last memory length of each mode no estimate moved by more than 3
        reported std (S2 needs a converged estimate; a sluggish start from a small P(0) still drifts)."""
        for i in range(self.K):
            then = self._estimate_ago(t, float(self.memory_s[i]))
            if then is None:
                return False
            for q in range(3):
                if not self.applicable(i, q):
                    continue
                x0, s0, x1, s1 = then[i, q], then[i, 3 + q], modal[i, q], modal[i, 3 + q]
                if not all(math.isfinite(v) for v in (x0, s0, x1, s1)):
                    return False
                if abs(x1 - x0) > 3.0 * s1:
                    return False
        return True

    # -- views
    @property
    def flags(self) -> np.ndarray:
        """(K, 3) bool: confirmed fault per mode and quantity."""
        return np.array([[t.flag for t in row] for row in self.tests], dtype=bool)

    @property
    def levels(self) -> np.ndarray:
        """(K, 3) int :class:`Level` per mode and quantity."""
        return np.array([[int(t.level) for t in row] for row in self.tests], dtype=int)

    @property
    def directions(self) -> list[list[str]]:
        return [[t.direction_name for t in row] for row in self.tests]

    @property
    def open_events(self) -> list[FaultEvent]:
        return [t.event for row in self.tests for t in row if t.event is not None]

    def baseline_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """(value, std) of the baseline, NaN while there is none."""
        if self.baseline is None:
            return np.full((self.K, 3), np.nan), np.full((self.K, 3), np.nan)
        return self.baseline.value.copy(), self.baseline.std.copy()

    # -- joint confirmation (S6)
    @property
    def joint_armed(self) -> bool:
        """Some mode's deviations need the joint check's support (S6)."""
        return bool(self.joint_armed_modes.any())

    def awaiting_joint(self) -> list[tuple[int, int, float]]:
        """(mode, quantity, since) of each suspected deviation that only the joint check can confirm and that it
        does not support (yet): the mode's test cannot conclude, so the decision shows the mode blind, never OK."""
        return [(i, q, tst.since) for i, row in enumerate(self.tests) for q, tst in enumerate(row)
                if tst.state == "suspect" and (self.several_modes or self.joint_needed(i, q))
                and self.joint_streak[i, q] == 0]

    def joint_needed(self, i: int, q: int) -> bool:
        """A deviation of (mode ``i``, quantity ``q``) is confirmed only with the joint check's support (S6): the
        mode is armed (narrow excitation, or coupled to a weakly excited mode), or -- for damping and gain -- the
        estimator is under stress (S5): while the recursion re-converges after an abrupt change its damping and gain
        estimates can swing the wrong way or move in a neighbouring mode, where a joint fit of the window after the
        change does not. A natural frequency under stress keeps the recursion's faster confirmation, unless another
        mode's fault was confirmed in the same stress episode: the recursion's split between the modes is then
        re-converging too, and a second mode's deviation needs the joint fit's support."""
        if self.joint_armed_modes[i] or self.joint_reference_pending:
            return True
        if self.anomaly_since is None or self.joint_reference is None or not self.joint_reference.converged:
            return False
        other = any(e.mode != i + 1 and e.alarm_time_s >= self.anomaly_since for e in self.open_events)
        return q > 0 or other

    def arm_joint(self, verdict: JointVerdict) -> None:
        """The baseline window's joint fit: arm S6 when some applicable quantity is not identifiable jointly."""
        base = self.baseline
        if base is not None and base.source == "given":
            # the user's baseline is the reference; the fit says what the excitation identifies
            with np.errstate(divide="ignore", invalid="ignore"):
                peak = np.hypot(base.std[:, 1] / np.abs(base.value[:, 1]), base.std[:, 2] / np.abs(base.value[:, 2]))
            verdict = replace(verdict, value=base.value.copy(), std=base.std.copy(), peak_own_std=peak)
        self.joint = self.joint_reference = verdict
        if not verdict.converged:
            # the baseline window does not identify the joint model (narrow excitation: fewer lines than
            # parameters): the recursion's split between the modes is not evidence, every mode needs the joint
            # check's support, which no fit gives until a quiet window identifies the model (JointChecker.step)
            self.joint_armed_modes = np.ones(self.K, dtype=bool)
            return
        app = applicable_mask(self.structures)
        self.joint_armed_modes = verdict.armed_modes(app)

    @property
    def joint_reference_pending(self) -> bool:
        """The joint fit of the baseline did not converge: the data do not identify the joint model (yet)."""
        return self.joint_reference is not None and not self.joint_reference.converged

    def joint_basis(self) -> tuple[np.ndarray, np.ndarray]:
        """(value, std) a joint fit is compared with: the converged reference fit, else the baseline (while the
        reference is pending no fit confirms anything: :meth:`apply_joint`)."""
        ref = self.joint_reference
        if ref is not None and ref.converged:
            return ref.value, ref.std
        assert self.baseline is not None
        return self.baseline.value, self.baseline.std

    def apply_joint(self, t: float, verdict: JointVerdict) -> FaultUpdate:
        """One joint check while monitoring (S6): confirm what two consecutive checks support, clear what two no
        longer support. An unconverged fit judges nothing (streaks and events are kept)."""
        out = FaultUpdate()
        self.joint = verdict
        needed = self.joint_armed or self.anomaly_since is not None
        if not (needed and verdict.converged) or self.baseline is None or self.held:
            return out
        if self.joint_reference_pending:
            # the baseline window did not identify the joint model: a later fit that converges on the changed
            # plant has nothing trustworthy to be compared with, so it confirms nothing (the deviation stays blind)
            self.joint_streak[:] = 0
            return out
        sup = verdict.supported
        if self.anomaly_since is not None:
            app = applicable_mask(self.structures)
            moved = {int(i) for i in np.flatnonzero(np.any((sup != 0) & app, axis=1))}
            if len(moved) >= 2 and not any(e.mode - 1 in moved for e in self.open_events):
                # after an abrupt change of the output, a joint fit that moves several modes at once does not
                # point at one structural change (a sensor bias or drift refits every mode): nothing is confirmed
                self.joint_streak[:] = 0
                self.joint_several_modes_t = t
                return out
        same = (sup != 0) & (np.sign(self.joint_streak) == sup)
        self.joint_streak = np.where(same, self.joint_streak + sup, sup)
        ref_value, ref_std = self.joint_basis()
        for i in range(self.K):
            for q in range(3):
                test = self.tests[i][q]
                if test.state == "fault" and test.by_joint:
                    assert test.event is not None      # the fault state always carries its open event
                    if sup[i, q] == test.direction:
                        test.joint_miss = 0
                        test.event.value = float(verdict.value[i, q])
                        continue
                    test.joint_miss += 1
                    if test.joint_miss >= 2:
                        test.event.clear_time_s = t
                        out.closed.append(test.event)
                        test.event, test.state = None, "ok"
                        test.reset(t)
                    continue
                if test.state == "fault" or abs(self.joint_streak[i, q]) < 2 or not self.applicable(i, q) \
                        or not (self.joint_armed_modes[i] or self.anomaly_since is not None):   # recursion alone
                    continue
                sigma = math.hypot(float(verdict.std[i, q]), float(ref_std[i, q]))
                dev = float(verdict.value[i, q] - ref_value[i, q])
                onset = verdict.window_s[0] if math.isnan(test.since) else min(test.since, verdict.window_s[0])
                ev = test.open_joint(t, onset, int(sup[i, q]), float(ref_value[i, q]), float(verdict.value[i, q]),
                                     dev / sigma if sigma > 0 else math.inf)
                out.opened.append(ev)
                self.events.append(ev)
        return out

    def joint_due(self, t: float, last_check: float) -> bool:
        """Whether a joint check is due (S6): every half memory while a test deviates or a joint event is open,
        else every two memory lengths."""
        needed = self.joint_armed or (self.anomaly_since is not None and self.joint_reference is not None)
        if not needed or self.phase != "monitoring":
            return False
        busy = any(tst.state != "ok" for row in self.tests for tst in row) or bool(np.any(self.joint_streak))
        period = (0.5 if busy else 2.0) * float(self.memory_s.max())
        return math.isnan(last_check) or t - last_check >= period

    # -- persistence
    def get_state(self) -> dict[str, Any]:
        """JSON-serializable state (baseline, learner, tests, phase, events)."""
        return {"version": 1, "K": self.K, "memory_s": self.memory_s.tolist(), "phase": self.phase,
                "t_phase": self.t_phase, "t_last": self.t_last,
                "baseline": None if self.baseline is None else self.baseline.to_dict(),
                "learner": self.learner.to_dict(),
                "tests": [[t.to_dict() for t in row] for row in self.tests],
                "history": [[tp, m.tolist()] for tp, m in self.history], "settle_forced": self.settle_forced,
                "anomaly_since": self.anomaly_since,
                "break_t": self.break_t, "events": [e.to_dict() for e in self.events],
                "joint_armed_modes": self.joint_armed_modes.tolist(),
                "joint": None if self.joint is None else self.joint.to_dict(),
                "joint_reference": None if self.joint_reference is None else self.joint_reference.to_dict(),
                "joint_streak": self.joint_streak.tolist(),
                "fast_until": [x if math.isfinite(x) else None for x in self.fast_until.tolist()],
                "fast_spent": self.fast_spent.tolist()}

    def set_state(self, state: Mapping[str, Any]) -> None:
        """Restore :meth:`get_state` output (same number of modes)."""
        if int(state.get("K", -1)) != self.K:
            raise FaultConfigError(f"saved fault state has {state.get('K')} modes, configuration has {self.K}")
        self.phase, self.t_phase, self.t_last = str(state["phase"]), float(state["t_phase"]), float(state["t_last"])
        self.baseline = None if state["baseline"] is None else Baseline.from_dict(state["baseline"])
        if self.settings.has_given_baseline:
            self.baseline = Baseline.given(self.settings, self.K)
        self.learner.load(state["learner"])
        self.history = deque((float(tp), np.asarray(m, float)) for tp, m in state.get("history", []))
        self.settle_forced = bool(state.get("settle_forced", False))
        self.anomaly_since = state.get("anomaly_since")
        self.break_t = float(state.get("break_t", math.nan))
        self.tests = [[SequentialTest.from_dict(d) for d in row] for row in state["tests"]]
        armed = state.get("joint_armed_modes", [bool(state.get("joint_armed", False))] * self.K)
        self.joint_armed_modes = np.asarray(armed, dtype=bool).reshape(self.K)
        self.joint = None if state.get("joint") is None else JointVerdict.from_dict(state["joint"])
        ref = state.get("joint_reference")
        self.joint_reference = None if ref is None else JointVerdict.from_dict(ref)
        self.joint_streak = np.asarray(state.get("joint_streak", np.zeros((self.K, 3))), dtype=int)
        until = state.get("fast_until") or [None] * self.K
        self.fast_until = np.array([-math.inf if x is None else float(x) for x in until], dtype=float).reshape(self.K)
        self.fast_spent = np.asarray(state.get("fast_spent", [False] * self.K), dtype=bool).reshape(self.K)
        by_key = {(e.mode, e.quantity, e.onset_time_s): e for row in self.tests for t in row
                  if (e := t.event) is not None}
        self.events = [by_key.get((d["mode"], d["quantity"], d["onset_time_s"])) or FaultEvent(**d)
                       for d in state["events"]]


# ----------------------------------------------------------------------------------------------- health
MODE_SCOPE = ":mode"
"""Key suffix of a health issue scoped to one mode (``loss_of_excitation:mode4``)."""


@dataclass
class HealthStatus:
    """Estimator/data health at one report (S5); ``hold`` means structural alarms are held back."""

    level: Level
    reasons: list[str]
    hold: bool                      # an issue holds every mode
    values: dict[str, Any]
    holds: list[Hold] = field(default_factory=list)   # every active hold (owner, reason, end, modes)

    def mode_hold(self, n_modes: int) -> np.ndarray:
        """(K,) bool: the mode's tests are held (by an issue of every mode or of its own)."""
        return np.array([any(h.holds(i) for h in self.holds) or self.hold for i in range(n_modes)], dtype=bool)

    @property
    def ok(self) -> bool:
        return self.level == Level.OK

    def to_dict(self) -> dict[str, Any]:
        return {"level": int(self.level), "ok": self.ok, "hold": self.hold, "reasons": list(self.reasons),
                **self.values}


class HealthMonitor:
    """Estimator health, separate from structural faults (S5).

    Issues are either *states* seen at an assessment (divergence, projection storm, loss of excitation,
    residual-variance jump) or *incidents* noted by the pipeline (:meth:`note`: data gap, non-finite or
    stuck sensor, out-of-order stamps, re-initialization). Each stays active for a hold-off of
    ``health.holdoff_memory_lengths`` x the longest memory after it was last seen, because the estimate
    needs that long to re-converge.
    """

    ERROR_KINDS = ("divergence", "stuck_sensor", "reinitializing", "no_valid_model", "time_scale")
    SHORT_KINDS = ("nonfinite", "outlier", "data_gap", "repriming", "duplicate_stamps", "out_of_order", "clock_step")
    """Data problems that do not move the estimate: skipped samples (no update; the kernel holds the input and
    predicts the output), samples dropped for their stamps (a recorder duplicate, a clock stepped back: the grid goes
    on as after a short gap) and breaks whose filter transient the estimator's own re-prime hold covers. They hold
    the tests while they last plus ``health.holdoff_min_s``, not for the re-convergence hold-off."""
    ADVISORY_KINDS = ("residual_jump", "projection_storm")
    """Also the signature of a genuine abrupt structural change: they do not hold structural alarms back,
    they only require that a confirmed fault began together with them (FaultMonitor ``suspect_since``)."""

    def __init__(self, memory_s: Sequence[float] | np.ndarray, settings: FaultSettings | None = None, *,
                 reference_modal: np.ndarray | None = None, structures: Sequence[SubmodelStructure] | None = None,
                 rate_hz: float | None = None) -> None:
        self.memory_s = np.asarray(memory_s, dtype=float)
        self.K = self.memory_s.size
        self.settings = settings or FaultSettings()
        self.structures = list(structures) if structures is not None else [SubmodelStructure()] * self.K
        self.reference_modal = None if reference_modal is None else np.asarray(reference_modal, float)[:, :3]
        self.rate_hz = rate_hz
        self.active: dict[str, tuple[float, str]] = {}   # kind -> (last seen time, message)
        self.first_seen: dict[str, float] = {}            # kind -> start of the current episode
        self.counts: dict[str, int] = {}
        self.residual_ref = math.nan
        self.last_projections: float | None = None
        self.last_samples: float | None = None
        self.t_last = math.nan

    @property
    def holdoff_s(self) -> float:
        s = self.settings
        return max(s.health_holdoff_min_s, s.health_holdoff_memory_lengths * float(self.memory_s.max()))

    def hold_of(self, kind: str) -> float:
        """Hold-off (s) after the last sighting of an issue of this kind (see ``SHORT_KINDS``)."""
        return self.settings.health_holdoff_min_s if kind in self.SHORT_KINDS else self.holdoff_s

    def note(self, kind: str, t: float, message: str, count: int = 1, *, mode: int | None = None) -> None:
        """Record an incident at time ``t`` (s); it stays active for the hold-off. ``mode`` (0-based) scopes it to
        one mode: it then holds that mode's tests only (:mod:`.decision`)."""
        key = kind if mode is None else f"{kind}{MODE_SCOPE}{mode + 1}"
        self.active[key] = (t, message)
        self.first_seen.setdefault(key, t)
        self.counts[kind] = self.counts.get(kind, 0) + count

    def clear_reference(self, modal: np.ndarray | None = None) -> None:
        """New reference for the parameter blow-up check (e.g. after a re-initialization)."""
        self.reference_modal = None if modal is None else np.asarray(modal, float)[:, :3].copy()
        self.residual_ref = math.nan

    def assess(self, t: float, modal: np.ndarray, est_health: EstimatorHealth | None = None) -> HealthStatus:
        """Check the estimate and the estimator's health record at time ``t`` and return the status (S5); a check
        whose item the estimator does not report (empty, ``None``) is skipped."""
        s = self.settings
        est = est_health if est_health is not None else EstimatorHealth()
        values: dict[str, Any] = {}
        modal = np.asarray(modal, dtype=float)
        # divergence: non-finite or blown-up parameters ([RA-SRIVC] §4.7 projection keeps A_i stable, not bounded)
        if not np.all(np.isfinite(modal[:, :3])):
            self.note("divergence", t, "divergence: non-finite estimate")
        elif self.reference_modal is not None:
            ref = self.reference_modal
            with np.errstate(divide="ignore", invalid="ignore"):
                ratio = np.abs(modal[:, :3] / ref)
            cols = [0, 2]
            r = ratio[:, cols]
            ok = np.isfinite(r) & (r > 0)
            bad = ok & ((r > s.health_max_parameter_ratio) | (r < 1.0 / s.health_max_parameter_ratio))
            bad |= ~ok & (ref[:, cols] != 0)
            if np.any(bad):
                i = int(np.argwhere(bad)[0][0])
                self.note("divergence", t, f"divergence: mode {i + 1} moved by more than a factor "
                          f"{s.health_max_parameter_ratio:g} from its reference")
        # loss of excitation: relative std of frequency / gain from sigma^2 P_bar (it winds up without excitation;
        # the published IV-sandwich std does not, core/recursive.py covariances); the reported std if not given
        with np.errstate(divide="ignore", invalid="ignore"):
            rel_std = np.abs(modal[:, 3:6] / modal[:, :3])
        rel = np.array([[rel_std[i, 0] if self.structures[i].n == 2 else 0.0, rel_std[i, 2]] for i in range(self.K)])
        if np.shape(est.information_relative_std) == (self.K,):
            rel = np.asarray(est.information_relative_std, dtype=float)[:, None]
        values["max_relative_std"] = float(np.nanmax(rel)) if np.any(np.isfinite(rel)) else math.nan
        for i in sorted({int(i) for i in np.argwhere(rel > s.health_max_relative_std)[:, 0]}):
            # a weakly excited mode blinds itself, not its neighbours (their estimates are judged on their own)
            self.note("loss_of_excitation", t, f"loss of excitation: mode {i + 1} relative std "
                      f"{np.nanmax(rel[i]):.2g} > {s.health_max_relative_std:g}", mode=i)
        # published std unavailable: a non-finite or indefinite covariance block reports NaN, never 0
        for i, p in enumerate(est.covariance_problems):
            if p:
                self.note("invalid_uncertainty", t, f"no valid uncertainty (std NaN): mode {i + 1} covariance "
                          f"block {p}", mode=i)
        if est.cond:
            conds = np.asarray(est.cond, float)
            c = float(np.nanmax(conds))
            values["condition"] = c
            per_mode = conds.shape == (self.K,)
            scopes: list[int | None] = list(range(self.K)) if per_mode else [None]
            for scope in scopes:
                ci = c if scope is None else float(conds[scope])
                if not ci <= s.health_max_condition:
                    which = "" if scope is None else f"mode {scope + 1} "
                    self.note("loss_of_excitation", t, f"loss of excitation: {which}IV condition number {ci:.3g} > "
                              f"{s.health_max_condition:.3g}", mode=scope)
        # projection storm: fraction of updates that needed the stability projection ([RA-SRIVC] §4.7)
        if est.projections:
            p_now = float(np.sum(np.asarray(est.projections, float)))
            n_now = float(est.updates)
            if self.last_projections is not None and self.last_samples is not None and n_now > self.last_samples:
                frac = (p_now - self.last_projections) / (n_now - self.last_samples)
                values["projection_fraction"] = frac
                if frac > s.health_max_projection_fraction:
                    self.note("projection_storm", t, f"projection storm: {frac:.1%} of updates needed the "
                              "stability projection")
            self.last_projections, self.last_samples = p_now, n_now
        # residual variance jump against a slow reference learned while healthy
        if est.residual_var is not None:
            rv = float(est.residual_var)
            values["residual_var"] = rv
            if math.isfinite(rv) and rv >= 0:
                if math.isnan(self.residual_ref):
                    self.residual_ref = rv
                ratio_r = rv / self.residual_ref if self.residual_ref > 0 else 1.0
                values["residual_ratio"] = ratio_r
                if ratio_r > s.health_residual_jump_ratio:
                    self.note("residual_jump", t, f"residual variance jumped x{ratio_r:.3g} over its healthy level")
                elif (not self.active and ratio_r < 1.5) or ratio_r < 1.0:
                    # the healthy level follows slow benign changes only: never absorbs a jump
                    dt = 0.0 if math.isnan(self.t_last) else max(t - self.t_last, 0.0)
                    a = min(1.0, dt / (10.0 * float(self.memory_s.max())))
                    self.residual_ref += a * (rv - self.residual_ref)
            elif not math.isfinite(rv):
                self.note("divergence", t, "divergence: non-finite residual variance")
        self.t_last = t
        status = self.status(t)
        status.values.update(values)
        return status

    def status(self, t: float) -> HealthStatus:
        """Active issues at ``t`` (expired ones are dropped); ``values['new_issues']`` were seen at ``t``.

        ``hold`` is True while an issue that holds every mode is active; ``holds`` lists every active hold as a
        :class:`.decision.Hold` (owner, reason, since, end, modes), the ones scoped to a mode included."""
        reasons = []
        level = Level.OK
        new = []
        hold = False
        holds: list[Hold] = []
        advisory_since: float | None = None
        for key, (t_seen, msg) in list(self.active.items()):
            kind, _, scope = key.partition(MODE_SCOPE)
            hold_s = self.hold_of(kind)
            if t - t_seen > hold_s:
                del self.active[key]
                continue
            if t_seen >= t:
                new.append(kind)
            suffix = "" if t_seen >= t else f" (recovering, hold-off until t={t_seen + hold_s:.1f} s)"
            reasons.append(msg + suffix)
            level = max(level, Level.ERROR if kind in self.ERROR_KINDS else Level.WARN)
            first = self.first_seen.get(key, t_seen)
            if kind in self.ADVISORY_KINDS:
                advisory_since = first if advisory_since is None else min(advisory_since, first)
                continue
            modes = (int(scope) - 1,) if scope else None
            holds.append(Hold(kind, msg, first, t_seen + hold_s, modes))
            hold = hold or modes is None
        for key in list(self.first_seen):
            if key not in self.active:
                del self.first_seen[key]
        values = {"counts": dict(self.counts), "issues": sorted({k.partition(MODE_SCOPE)[0] for k in self.active}),
                  "new_issues": sorted(set(new)), "advisory_since": advisory_since}
        return HealthStatus(level, reasons, hold, values, holds)

    def get_state(self) -> dict[str, Any]:
        return {"active": {k: list(v) for k, v in self.active.items()}, "counts": dict(self.counts),
                "first_seen": dict(self.first_seen),
                "residual_ref": self.residual_ref, "last_projections": self.last_projections,
                "last_samples": self.last_samples, "t_last": self.t_last,
                "reference_modal": None if self.reference_modal is None else self.reference_modal.tolist()}

    def set_state(self, d: Mapping[str, Any]) -> None:
        self.active = {k: (float(v[0]), str(v[1])) for k, v in d["active"].items()}
        self.counts = {k: int(v) for k, v in d["counts"].items()}
        self.first_seen = {k: float(v) for k, v in d.get("first_seen", {}).items()}
        self.residual_ref = float(d["residual_ref"])
        self.last_projections, self.last_samples = d["last_projections"], d["last_samples"]
        self.t_last = float(d["t_last"])
        rm = d.get("reference_modal")
        self.reference_modal = None if rm is None else np.asarray(rm, float)

