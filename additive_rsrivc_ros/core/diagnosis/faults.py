"""Structural fault tests on the stream of modal estimates, kept apart from the estimator's health.

The recursion ([RA-SRIVC] Algorithm 2) publishes per mode ``[f_hz, zeta, gain]`` and their std (delta method on
``sigma^2 P_bar``). The steps below are cited by name (S1-S6; S7 fast tracking) in the fault modules' docstrings:

* S1 autocorrelation: with memory ``T`` the estimate is close to AR(1); ``tau_c = 2 T``, ``n_eff = W / (2 T)``.
* S2 baseline: mean over a healthy window, ``s_x = max(reported, empirical std)``, ``s_b = s_x / sqrt(n_eff)``.
* S3 test: two-sided CUSUM (Page 1954) on ``z = (x - b) / sqrt(s_x^2 + s_b^2)``, increments weighted ``dt / tau_c``,
  reference tuned to the minimum relevant change; the change time is the CUSUM's last zero.
* S4 decision: suspect when ``g > h`` and the deviation is relevant; fault after the persistence time; clear with
  hysteresis (``clear_fraction`` and the clear time).
* S5 health (:mod:`.health`): data and estimator problems hold the tests (one mode's problem holds that mode only,
  :mod:`.decision`); advisory stress restricts confirmation for a bounded window.
* S6 joint confirmation (:mod:`.joint_check`): where a joint fit is needed, a deviation needs its support.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ..model import SubmodelStructure
from ..params import settings_as_params
from .baseline import Baseline, BaselineLearner
from .baseline_phases import BaselinePhases
from .deviations import deviations, leads, peak_moved
from .estimate_history import EstimateHistory
from .fast_tracking import FAST_DECAY_TIMES, FastTracking
from .fault_settings import FaultConfigError, FaultSettings, FaultSetup, Level
from .health import MODE_SCOPE, HealthMonitor, HealthStatus
from .joint_check import JointVerdict, applicable_mask
from .joint_confirmation import JointConfirmation
from .sequential_test import FaultEvent, FaultUpdate, SequentialTest, SequentialTests, cusum_threshold
from .stress_episode import StressEpisode

__all__ = ["FAST_DECAY_TIMES", "MODE_SCOPE", "Baseline", "BaselineLearner", "FaultConfigError", "FaultEvent",
           "FaultMonitor", "FaultSettings", "FaultSetup", "FaultUpdate", "HealthMonitor", "HealthStatus", "Level",
           "SequentialTest", "SequentialTests", "cusum_threshold"]


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
    Its parts own their state (modules named): the phases (baseline_phases), recent estimates (estimate_history),
    the tests (sequential_test), the stress episode (stress_episode), the joint confirmation (joint_confirmation)
    and the fast tracking (fast_tracking); the monitor combines them in :meth:`update`.
    """

    def __init__(self, memory_s: Sequence[float] | np.ndarray, settings: FaultSettings | None = None, *,
                 structures: Sequence[SubmodelStructure] | None = None) -> None:
        self.setup = FaultSetup.of(memory_s, settings, structures)
        self.K = self.setup.K
        self.mode_tests = SequentialTests(self.K)
        self.recent = EstimateHistory(self.setup)
        self.phases = BaselinePhases(self.setup, self.mode_tests, self.recent)
        self.stress = StressEpisode(self.setup)
        self.joint_confirmation = JointConfirmation(self.setup, self.mode_tests, self.phases, self.stress)
        self.fast = FastTracking(self.setup)
        self.t_last = math.nan
        self.held = False
        self.last_modal = np.full((self.K, 6), np.nan)

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
        self.setup.settings = new
        if new.baseline_value != old.baseline_value or new.baseline_std != old.baseline_std:
            if new.has_given_baseline:
                self.phases.apply_given(new)
            elif old.has_given_baseline:
                self.rebaseline(self.t_last)

    def set_memory(self, memory_s: Sequence[float] | np.ndarray) -> None:
        """Follow a runtime memory change (time constants of S1 and of the persistence/clear times)."""
        m = np.asarray(memory_s, dtype=float)
        if m.shape != self.memory_s.shape or not np.all(m > 0):
            raise FaultConfigError(f"memory_s must list {self.K} positive values")
        self.setup.memory_s = m

    @property
    def memory_s(self) -> np.ndarray:
        return self.setup.memory_s

    @property
    def settings(self) -> FaultSettings:
        return self.setup.settings

    @property
    def structures(self) -> list[SubmodelStructure]:
        return self.setup.structures

    # -- derived times
    @property
    def settle_s(self) -> float:
        return self.setup.settle_s

    @property
    def baseline_window_s(self) -> float:
        return self.setup.baseline_window_s

    def persistence_s(self, i: int) -> float:
        s = self.settings
        return max(s.persistence_s, s.persistence_memory_lengths * self.effective_memory_s(i))

    def memory_scale(self) -> np.ndarray:
        """(K,) factor on each mode's configured memory the estimator should use now (S7,
        :meth:`.fast_tracking.FastTracking.memory_scale`)."""
        return self.fast.memory_scale(self.t_last, self.baseline)

    def effective_memory_s(self, i: int) -> float:
        """Mode ``i``'s memory as the estimator uses it now (S7): its estimates decorrelate, and a transient in them
        fades, within it."""
        return self.fast.effective_memory_s(i, self.t_last, self.baseline)

    def clear_time_s(self, i: int) -> float:
        return self.setup.clear_time_s(i)

    def applicable(self, i: int, q: int) -> bool:
        """Frequency and damping are tested only for second-order modes (a rigid body has only a gain)."""
        return self.setup.applicable(i, q)

    # -- main step
    def rebaseline(self, t: float) -> list[FaultEvent]:
        """Forget the baseline and learn a new one from now on; open events are closed at ``t``."""
        closed = self.mode_tests.close_all(t)
        self.phases.restart(t)
        self.stress.end()
        self.joint_confirmation.reset()
        self.fast.reset()
        return closed

    def update(self, t: float, modal: np.ndarray, *, hold: bool = False,
               suspect_since: float | None = None, mode_hold: Sequence[bool] | np.ndarray | None = None,
               model_flagged: bool = False) -> FaultUpdate:
        """Process one modal estimate (K, 6) at time ``t`` (s); see the class docstring.

        ``suspect_since`` (S5, advisory issues such as a residual-variance jump): under stress since then, a fault is
        confirmed only if it is the mode's leading deviation (its natural frequency when relevant, else the largest
        ``|z|``) and began within two memory lengths of the stress (five for a frequency, from its onset); several
        modes that deviate or travel at once confirm nothing by themselves. The isolation is bounded
        (:meth:`restricted_until`). Damping and gain are confirmed only once they and the frequency hold still.

        ``mode_hold`` (K,) bool: holds scoped to single modes (:mod:`.decision`): a held mode's tests are reset
        (an open event stays open); the others are judged on their own. ``model_flagged``: the model-order check
        flags the model; every deviation then needs the joint check's support (S6).
        """
        out = FaultUpdate()
        modal = np.asarray(modal, dtype=float)
        if modal.shape != (self.K, 6):
            raise ValueError(f"modal estimate must have shape ({self.K}, 6), got {modal.shape}")
        dt = 0.0 if math.isnan(self.t_last) else max(t - self.t_last, 0.0)
        self.t_last = t
        self.last_modal = modal.copy()
        self.joint_confirmation.model_flagged = bool(model_flagged)
        finite = bool(np.all(np.isfinite(modal[:, :3])))
        self.held = hold or not finite
        if self.phases.step(t, modal, self.held, suspect_since, out):
            return out
        base = self.baseline
        if not self.settings.enabled or base is None:
            return out
        app = applicable_mask(self.structures)
        sigma, rho, relevant, score = deviations(modal, base, self.settings, app)
        stress_since = self.stress.follow(t, suspect_since, self.phases.t_phase)
        held_mode = np.zeros(self.K, dtype=bool) if mode_hold is None else np.asarray(mode_hold, dtype=bool)
        deviating = np.any(relevant & (score >= 0), axis=1) & ~held_mode
        memory_now = [self.effective_memory_s(i) for i in range(self.K)]
        moving = self.recent.moving(t, modal, rho, memory_now)
        # under stress a mode whose estimate still travels takes part in the change as much as one that deviates
        # already: a lightly damped mode's frequency crosses its relevance long after a broad neighbour's
        self.stress.judge_modes(t, deviating | (np.any(moving, axis=1) & ~held_mode), self.open_events)
        self.joint_confirmation.forget_refusals()
        open_modes = np.zeros(self.K, dtype=bool)
        open_modes[[e.mode - 1 for e in self.open_events]] = True
        self.joint_confirmation.judge_coupled(deviating | (open_modes & ~held_mode))
        self.joint_confirmation.judge_together(relevant & (score >= 0) & ~held_mode[:, None])
        quiet = np.array([all(tst.state == "ok" for tst in row[1:]) for row in self.tests]) & ~held_mode
        peaks = peak_moved(modal, base, sigma, self.settings.min_change[2], app)
        self.joint_confirmation.judge_peak(t, np.where(quiet, peaks, np.nan))
        lead = leads(score, app, np.array([[tst.state == "fault" for tst in row] for row in self.tests]))
        arriving = self.recent.moving(t, modal, rho, memory_now, lookback=0.5)
        travel = np.zeros((self.K, 3), dtype=bool)
        for i in range(self.K):
            w = min(1.0, dt / (2.0 * self.effective_memory_s(i)))   # S1: weight per independent sample
            if held_mode[i]:
                for test in self.tests[i]:
                    test.reset(t)       # evidence gathered under the hold is not evidence; an open event stays
                continue
            self.fast.track(i, t, self.tests[i])
            travelling = [bool(moving[i, 0] or arriving[i, q]) for q in range(3)]
            travel[i] = travelling
            self._step_mode(i, t, w, modal, base, sigma[i], rho[i], travelling, stress_since, int(lead[i]), out)
        self.joint_confirmation.judge_travel(travel)
        return out

    def _step_mode(self, i: int, t: float, w: float, modal: np.ndarray, base: Baseline, sigma: np.ndarray,
                   rho: np.ndarray, travelling: list[bool], stress_since: float | None, lead: int,
                   out: FaultUpdate) -> None:
        """Step mode ``i``'s tests (S3, S4) with weight ``w``; ``sigma``, ``rho`` and ``travelling`` per quantity."""
        s = self.settings
        for q in range(3):
            if not self.applicable(i, q):
                continue
            b = float(base.value[i, q])
            if b == 0.0 or not math.isfinite(b):
                continue
            test = self.tests[i][q]
            if test.by_joint:
                continue        # S6: the joint check holds and clears its own events
            test.confirm_by_onset = q == 0
            # S6: where the joint check is needed, its support names the direction too (a lightly damped mode's
            # damping rise read by the re-converging recursion as a drop)
            test.confirm_direction = int(np.sign(self.joint_streak[i, q])) if self.joint_needed(i, q) else 0
            test.confirm_before = -math.inf if self.stress.several_modes else self._confirm_before(
                i, q, travelling[q], stress_since, lead)
            opened, closed = test.step(
                t, w, float(modal[i, q]), float(sigma[q]), b, float(rho[q]), s.cusum_reference_sigma,
                s.cusum_threshold, s.clear_fraction, self.persistence_s(i), self.clear_time_s(i),
                arl0=self.setup.arl0_samples(i))
            if opened is not None:
                out.opened.append(opened)
                self.events.append(opened)
            if closed is not None:
                out.closed.append(closed)

    def restricted_until(self, i: int) -> float | None:
        """End of mode ``i``'s isolation window under the current stress episode (None without one)."""
        return self.stress.restricted_until(i)

    def _confirm_before(self, i: int, q: int, travelling: bool, stress_since: float | None, lead: int) -> float:
        """Latest onset of a deviation of (mode ``i``, quantity ``q``) that may still be confirmed (S4-S6)."""
        if self.model_flagged or (self.joint_needed(i, q) and self.joint_streak[i, q] == 0):
            return -math.inf        # S6: a flagged model names nothing; the data do not support this deviation jointly
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
        if self.t_last >= stress_since + self.stress.window_s(i, q):
            return math.inf         # the isolation window has passed: judged against the baseline
        if q == lead:
            return stress_since + self.stress.window_s(i, q)   # the deviation must begin with the stress
        return -math.inf            # isolation under stress: only the mode's dominant deviation can be the fault

    def converged(self, t: float, modal: np.ndarray) -> bool:
        """The estimate has settled (:meth:`.estimate_history.EstimateHistory.converged`)."""
        return self.recent.converged(t, modal)

    # -- views of the parts
    @property
    def tests(self) -> list[list[SequentialTest]]:
        """The (K x 3) sequential tests, rows by mode."""
        return self.mode_tests.rows

    @property
    def events(self) -> list[FaultEvent]:
        """Every event ever opened (the open ones are also held by their tests)."""
        return self.mode_tests.events

    @property
    def open_events(self) -> list[FaultEvent]:
        return self.mode_tests.open_events

    @property
    def flags(self) -> np.ndarray:
        """(K, 3) bool: confirmed fault per mode and quantity."""
        return self.mode_tests.flags

    @property
    def levels(self) -> np.ndarray:
        """(K, 3) int :class:`Level` per mode and quantity."""
        return self.mode_tests.levels

    @property
    def directions(self) -> list[list[str]]:
        return self.mode_tests.directions

    @property
    def phase(self) -> str:
        return self.phases.phase

    @property
    def learner(self) -> BaselineLearner:
        return self.phases.learner

    @property
    def baseline(self) -> Baseline | None:
        return self.phases.baseline

    @property
    def baseline_trusted(self) -> bool:
        """False while monitoring against a baseline learned over less than half a window."""
        return self.phases.trusted

    def baseline_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """(value, std) of the baseline, NaN while there is none."""
        if self.baseline is None:
            return np.full((self.K, 3), np.nan), np.full((self.K, 3), np.nan)
        return self.baseline.value.copy(), self.baseline.std.copy()

    @property
    def anomaly_since(self) -> float | None:
        """Start of the advisory stress episode (S5), None without one."""
        return self.stress.anomaly_since

    # -- joint confirmation (S6, :class:`.joint_confirmation.JointConfirmation`)
    @property
    def joint(self) -> JointVerdict | None:
        """The latest joint check."""
        return self.joint_confirmation.latest

    @property
    def joint_reference(self) -> JointVerdict | None:
        """The joint fit of the end of the baseline window."""
        return self.joint_confirmation.reference

    @joint_reference.setter
    def joint_reference(self, verdict: JointVerdict | None) -> None:
        self.joint_confirmation.reference = verdict

    @property
    def joint_armed_modes(self) -> np.ndarray:
        return self.joint_confirmation.armed_modes

    @property
    def joint_streak(self) -> np.ndarray:
        return self.joint_confirmation.streak

    @property
    def joint_several_modes_t(self) -> float:
        return self.joint_confirmation.several_modes_t

    @property
    def joint_armed(self) -> bool:
        """Some mode's deviations need the joint check's support (S6)."""
        return self.joint_confirmation.armed

    @property
    def joint_reference_pending(self) -> bool:
        """The joint fit of the baseline did not converge: the data do not identify the joint model (yet)."""
        return self.joint_confirmation.reference_pending

    def awaiting_joint(self) -> list[tuple[int, int, float]]:
        """(mode, quantity, since) of each suspected deviation that only the joint check can confirm and that it
        does not support (yet): the mode's test cannot conclude, so the decision shows the mode blind, never OK."""
        return self.joint_confirmation.awaiting()

    @property
    def model_flagged(self) -> bool:
        """The model-order check flags the model: no deviation is confirmed (S6)."""
        return self.joint_confirmation.model_flagged

    def peak_unresolved(self) -> list[tuple[int, float, float]]:
        """(mode, relative change, since) of each resonance peak that moved while neither its gain nor its damping
        deviates enough: only the joint check can name the quantity; the decision shows the mode blind."""
        return self.joint_confirmation.peak_unresolved()

    def joint_needed(self, i: int, q: int) -> bool:
        """A deviation of (mode ``i``, quantity ``q``) is confirmed only with the joint check's support (S6)."""
        return self.joint_confirmation.needed(i, q)

    def arm_joint(self, verdict: JointVerdict) -> None:
        """The baseline window's joint fit: arm S6 when some applicable quantity is not identifiable jointly."""
        self.joint_confirmation.arm(verdict)

    def joint_basis(self) -> tuple[np.ndarray, np.ndarray]:
        """(value, std) a joint fit is compared with: the converged reference fit, else the baseline."""
        return self.joint_confirmation.basis()

    def apply_joint(self, t: float, verdict: JointVerdict) -> FaultUpdate:
        """One joint check while monitoring (S6): confirm what two consecutive checks support, clear what two no
        longer support. An unconverged fit judges nothing but breaks the streaks (open events are kept)."""
        return self.joint_confirmation.apply(t, verdict, self.held)

    def joint_due(self, t: float, last_check: float) -> bool:
        """Whether a joint check is due (S6): every half memory while a test deviates or a joint event is open,
        else every two memory lengths."""
        return self.joint_confirmation.due(t, last_check)

    # -- persistence
    def get_state(self) -> dict[str, Any]:
        """JSON-serializable state (baseline, learner, tests, phase, events)."""
        ph = self.phases
        return {"version": 1, "K": self.K, "memory_s": self.memory_s.tolist(), "phase": ph.phase,
                "t_phase": ph.t_phase, "t_last": self.t_last,
                "baseline": None if ph.baseline is None else ph.baseline.to_dict(),
                "learner": ph.learner.to_dict(), "tests": self.mode_tests.to_dicts(),
                "history": self.recent.to_list(), "settle_forced": ph.settle_forced,
                "anomaly_since": self.stress.anomaly_since, "several_since": self.stress.several_since,
                "break_t": ph.break_t, "events": [e.to_dict() for e in self.events],
                **self.joint_confirmation.to_dict(), **self.fast.to_dict()}

    def set_state(self, state: Mapping[str, Any]) -> None:
        """Restore :meth:`get_state` output (same number of modes)."""
        if int(state.get("K", -1)) != self.K:
            raise FaultConfigError(f"saved fault state has {state.get('K')} modes, configuration has {self.K}")
        self.t_last = float(state["t_last"])
        self.phases.load(state)
        self.stress.load(state.get("anomaly_since"), state.get("several_since"))
        self.mode_tests.load(state["tests"], state["events"])
        self.joint_confirmation.load(state)
        self.fast.load(state)
