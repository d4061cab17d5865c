"""The fault monitor's phases before its tests run (S2, S5 of :mod:`.faults`): waiting, settling, learning.

``waiting`` (no estimate yet) -> ``settling`` (settle_memory_lengths x the longest memory, until the estimate has
converged) -> ``learning`` (the baseline window) -> ``monitoring``; with a given baseline the learning phase is
skipped. A hold pauses a window in progress; it resumes once the estimate has re-settled, unless the estimate then
differs from what was learned by a relevant change, in which case the partial window becomes the baseline
(untrusted below half a window). The same guard runs on every estimate of the window, and the window's first and
last thirds are compared at its end, so a plant change never becomes the baseline silently.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from ..vocabulary import QUANTITIES
from .baseline import Baseline, BaselineLearner
from .estimate_history import EstimateHistory
from .fault_settings import FaultSettings, FaultSetup
from .sequential_test import FaultUpdate, SequentialTests


class BaselinePhases:
    """Phase (``phase`` since ``t_phase``), the baseline learner and the baseline; resets ``tests`` when monitoring
    starts and while held, and remembers the estimates in ``recent``."""

    def __init__(self, setup: FaultSetup, tests: SequentialTests, recent: EstimateHistory) -> None:
        self.setup = setup
        self.tests = tests
        self.recent = recent
        self.learner = BaselineLearner(setup.K)
        self.baseline: Baseline | None = Baseline.given(setup.settings, setup.K) \
            if setup.settings.has_given_baseline else None
        self.phase = "waiting"
        self.t_phase = math.nan
        self.settle_forced = False
        self.break_t = math.nan                   # first data problem that paused the current baseline window

    @property
    def trusted(self) -> bool:
        """False while monitoring against a baseline learned over less than half a window."""
        return self.baseline is None or self.baseline.trusted

    def restart(self, t: float) -> None:
        """Forget the baseline; learn a new one from ``t`` on (once settled if not learning or monitoring yet)."""
        self.baseline = None
        self.break_t = math.nan
        if self.phase in ("learning", "monitoring"):
            self.phase, self.t_phase = "learning", t
            self.learner.reset(t)

    def apply_given(self, settings: FaultSettings) -> None:
        """A baseline given at runtime replaces the current one (and ends a window in progress)."""
        self.baseline = Baseline.given(settings, self.setup.K)
        if self.phase == "learning":
            self.phase = "monitoring"

    def step(self, t: float, modal: np.ndarray, held: bool, suspect_since: float | None, out: FaultUpdate) -> bool:
        """Hold, settling and baseline learning for the estimate ``modal`` at ``t``; True when this update ends here
        (no test step). ``held``: a data or estimator problem; ``suspect_since``: advisory stress since then."""
        if self.phase == "waiting":
            self.phase, self.t_phase = "settling", t
        if held:
            if self.phase == "learning":
                # a data problem (gap, re-priming, sensor, re-initialization) during the window: keep what was
                # learned, pause, and resume once the estimate has re-settled (see _resume_window)
                self.learner.pause()
                self.phase, self.t_phase = "settling", t - self.setup.settle_s
                if math.isnan(self.break_t):
                    self.break_t = t
            self.tests.reset(t)
            return True
        self.recent.remember(t, modal)
        if self.phase == "settling" and self._settling(t, modal, out):
            return True
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
            self._learn(t, modal, out)
            return True
        return False

    def _settling(self, t: float, modal: np.ndarray, out: FaultUpdate) -> bool:
        """Wait for the estimate to settle, then monitor (given baseline), resume a paused window or start one; True
        when this update ends here."""
        if t - self.t_phase < self.setup.settle_s:
            return True
        forced = t - self.t_phase >= self.setup.settings.settle_max_memory_lengths * float(self.setup.memory_s.max())
        if not (forced or self.recent.converged(t, modal)):
            return True
        self.settle_forced = forced and not self.recent.converged(t, modal)
        if self.baseline is not None:
            self._start_monitoring(t, t, out)
        elif self.learner.n > 0:
            if self._resume_window(t, modal, out):
                return True
        else:
            self.phase, self.t_phase = "learning", t
            self.learner.reset(t)
        return False

    def _learn(self, t: float, modal: np.ndarray, out: FaultUpdate) -> None:
        """One estimate of the baseline window: keep the partial on a change, finish the window at its end."""
        change = self._window_change(modal)
        if change is not None:
            self._keep_partial(t, t, f"the estimate moved during the window ({change})", out)
            return
        window_s = self.setup.baseline_window_s
        self.learner.add(t, modal, window_s=window_s)
        if self.learner.elapsed_s >= window_s - 1e-9:
            self.baseline = self.learner.finish(self.setup.memory_s, self.learner.elapsed_s)
            moved = self._thirds_change()
            if moved is not None:
                # a change spread over the window (a slow fault, a still converging estimate) passes the check
                # of each estimate against the partial, whose spread grows with it: never a trusted baseline
                self.baseline.trusted = False
                self.baseline.note = (f"the estimate moved during the {self.learner.elapsed_s:.1f} s baseline "
                                      f"window ({moved} from its first third to its last); baseline untrusted")
            self.break_t = math.nan
            self._start_monitoring(t, t, out)

    def _window_change(self, modal: np.ndarray) -> str | None:
        """A relevant and significant deviation of ``modal`` from the partial baseline learned so far (S3 relevance
        ``rho`` and ``z >= 3`` with the partial's spread), as ``"mode i quantity +x.x %"``; None if there is none or
        too little was learned (fewer than two estimates)."""
        if self.learner.n < 2:
            return None
        part = self.learner.finish(self.setup.memory_s, self.learner.elapsed_s)
        sx = np.fmax(modal[:, 3:6], part.spread)
        return self._largest_change(modal[:, :3], part.value, np.sqrt(sx * sx + part.std ** 2), part.spread)

    def _largest_change(self, value: np.ndarray, ref: np.ndarray, sigma: np.ndarray,
                        spread: np.ndarray) -> str | None:
        """The largest relevant (S3 ``rho`` with the fluctuation ``spread``) and significant (``|dev| >= 3 sigma``)
        relative change of ``value`` from ``ref`` (K, 3) over the applicable quantities, as ``"mode i quantity
        +x.x %"``; None if there is none."""
        s = self.setup.settings
        with np.errstate(divide="ignore", invalid="ignore"):
            rho = np.maximum(np.asarray(s.min_change)[None, :], s.relevance_spread_factor * spread / np.abs(ref))
            dev = value - ref
            rel = dev / np.abs(ref)
            hit = (np.abs(rel) >= rho) & (np.abs(dev) >= 3.0 * sigma)
        best, text = -1.0, None
        for i in range(self.setup.K):
            for q in range(3):
                if self.setup.applicable(i, q) and bool(hit[i, q]) and abs(rel[i, q]) > best:
                    best, text = abs(rel[i, q]), f"mode {i + 1} {QUANTITIES[q]} {100.0 * rel[i, q]:+.1f} %"
        return text

    def _thirds_change(self) -> str | None:
        """A relevant and significant difference between the means of the window's first and last thirds (S3
        relevance ``rho`` with the larger third's spread, ``z >= 3`` with each third's S2 std), as ``"mode i quantity
        +x.x %"``."""
        thirds = self.learner.outer_thirds(self.setup.memory_s)
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
        window_s = self.setup.baseline_window_s
        base = self.learner.finish(self.setup.memory_s, elapsed)
        base.trusted = elapsed >= 0.5 * window_s
        base.note = (f"baseline learned over {elapsed:.1f} s of the {window_s:.1f} s window: {why}"
                     + ("" if base.trusted else "; baseline untrusted"))
        self.baseline = base
        self.break_t = math.nan
        self._start_monitoring(t, min(t_phase, t), out)

    def _start_monitoring(self, t: float, t_phase: float, out: FaultUpdate) -> None:
        """Enter the monitoring phase (its start ``t_phase``) with fresh tests."""
        self.phase, self.t_phase = "monitoring", t_phase
        out.baseline_ready = True
        self.tests.reset(t)

    def load(self, state: Mapping[str, Any]) -> None:
        """Restore the phase, baseline (a given one wins), learner, remembered estimates and window break from a
        :meth:`.faults.FaultMonitor.get_state` dict."""
        self.phase, self.t_phase = str(state["phase"]), float(state["t_phase"])
        self.baseline = None if state["baseline"] is None else Baseline.from_dict(state["baseline"])
        if self.setup.settings.has_given_baseline:
            self.baseline = Baseline.given(self.setup.settings, self.setup.K)
        self.learner.load(state["learner"])
        self.recent.load(state.get("history", []))
        self.settle_forced = bool(state.get("settle_forced", False))
        self.break_t = float(state.get("break_t", math.nan))
