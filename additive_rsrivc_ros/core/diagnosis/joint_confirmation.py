"""Joint confirmation (S6 of :mod:`.faults`): where the recursion's split between the modes is no evidence, a
deviation needs the support of the joint fit (:mod:`.joint_check`).

The baseline window's joint fit (the reference) arms the modes with a quantity the excitation does not identify
jointly; under advisory stress damping and gain need the joint support too; and so do the deviations of modes the
reference shows coupled (correlated quantities) while they deviate together: the recursion's split between them
re-converges after a change of either, so a change of one moves the other for a while. A damping or gain deviation whose
estimate still travels may be confirmed by the joint check too, instead of waiting for it to hold still. Two
consecutive joint checks that support a change confirm it (the event carries the joint fit's value), two that no
longer support it clear it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import replace
from typing import Any

import numpy as np

from ..vocabulary import QUANTITIES
from .baseline_phases import BaselinePhases
from .fault_settings import FaultSetup
from .joint_check import COUPLING, JointVerdict, applicable_mask
from .sequential_test import FaultUpdate, SequentialTest, SequentialTests
from .stress_episode import StressEpisode


class JointConfirmation:
    """Per mode whether it is armed (``armed_modes``), the latest joint check (``latest``), the baseline window's fit
    (``reference``), the signed run of consecutive supporting checks per mode and quantity (``streak``) and the last
    stressed check that moved several modes at once (``several_modes_t``)."""

    def __init__(self, setup: FaultSetup, tests: SequentialTests, phases: BaselinePhases,
                 stress: StressEpisode) -> None:
        self.setup = setup
        self.tests = tests
        self.phases = phases
        self.stress = stress
        # per mode: the baseline's joint fit found a quantity of that mode not identifiable; only such a mode's
        # deviations need the joint check's support (a weakly excited mode does not make its neighbours wait)
        self.armed_modes = np.zeros(setup.K, dtype=bool)
        self.latest: JointVerdict | None = None      # the latest joint check
        self.reference: JointVerdict | None = None   # the joint fit of the end of the baseline window
        self.streak = np.zeros((setup.K, 3), dtype=int)   # signed run of consecutive supporting checks
        self.several_modes_t = math.nan   # last stressed joint check that moved several modes at once
        # per mode: it deviates together with a mode the reference shows coupled to it (recomputed every update)
        self.coupled_pending = np.zeros(setup.K, dtype=bool)
        # per mode: the relative change of its resonance peak while gain and damping are quiet (NaN: none), since
        self.peak_change = np.full(setup.K, np.nan)
        self.peak_since = np.full(setup.K, np.nan)
        # per mode and quantity: it deviates together with the mode's gain (recomputed every update)
        self.together_pending = np.zeros((setup.K, 3), dtype=bool)
        # per mode and quantity: a damping or gain deviation under test whose estimate still travels, which the
        # recursion confirms only once it holds still (recomputed every update)
        self.travel_pending = np.zeros((setup.K, 3), dtype=bool)
        # the model-order check flags the model (a wrong optimum or too few modes; set every update)
        self.model_flagged = False
        # per mode and quantity: a joint check did not support the deviation under test; until that deviation ends
        # only the joint check confirms it (a held timer does not overrule a fit of the data)
        self.refused = np.zeros((setup.K, 3), dtype=bool)

    def reset(self) -> None:
        """Unarmed, no reference, no streak (a new baseline)."""
        self.armed_modes[:] = False
        self.latest, self.reference = None, None
        self.streak[:] = 0
        self.coupled_pending[:] = False
        self.together_pending[:] = False
        self.travel_pending[:] = False
        self.refused[:] = False
        self.peak_change[:] = np.nan
        self.peak_since[:] = np.nan

    @property
    def armed(self) -> bool:
        """Some mode's deviations need the joint check's support."""
        return bool(self.armed_modes.any())

    @property
    def reference_identified(self) -> bool:
        """The joint fit of the baseline converged: the data identify the joint model, and its coupling is known."""
        return self.reference is not None and self.reference.converged

    @property
    def reference_pending(self) -> bool:
        """The joint fit of the baseline did not converge: the data do not identify the joint model (yet)."""
        return self.reference is not None and not self.reference.converged

    def needed(self, i: int, q: int) -> bool:
        """A deviation of (mode ``i``, quantity ``q``) is confirmed only with the joint check's support: the mode is
        armed (narrow excitation, or coupled to a weakly excited mode), or -- for damping and gain -- the estimator is
        under stress (S5): while the recursion re-converges after an abrupt change its damping and gain estimates
        can swing the wrong way or move in a neighbouring mode, where a joint fit of the window after the change does
        not. A natural frequency under stress keeps the recursion's faster confirmation, unless another mode's fault
        was confirmed in the same stress episode: the recursion's split between the modes is then re-converging
        too, and a second mode's deviation needs the joint fit's support."""
        if self.armed_modes[i] or self.reference_pending or self._split_open(i, q):
            return True
        since = self.stress.anomaly_since
        if since is None or self.reference is None or not self.reference.converged:
            return False
        other = any(e.mode != i + 1 and e.alarm_time_s >= since for e in self.tests.open_events)
        return q > 0 or other

    def awaiting(self) -> list[tuple[int, int, float]]:
        """(mode, quantity, since) of each suspected deviation that only the joint check can confirm and that it
        does not support (yet) in the suspected direction."""
        return [(i, q, tst.since) for i, row in enumerate(self.tests) for q, tst in enumerate(row)
                if tst.state == "suspect" and (self.stress.several_modes or self.needed(i, q))
                and (self.model_flagged or np.sign(self.streak[i, q]) != tst.direction)]

    def judge_coupled(self, deviating: np.ndarray) -> None:
        """Mark the modes whose deviation coexists with one of a coupled mode (``deviating``, (K,) bool: a relevant
        deviation or an open event). Coupling is the reference fit's (|correlation| of two modes' quantities at
        least :data:`.joint_check.COUPLING`): overlapping resonances share the data, and after a change of one the
        recursion moves the other until its split re-converges (a damping change of one mode read as a frequency
        change of its neighbour), where a joint fit of the window after the change does not."""
        ref = self.reference
        self.coupled_pending[:] = False
        if ref is None or not self.reference_identified or ref.coupling is None:
            return
        coupled = np.asarray(ref.coupling, float) >= COUPLING
        np.fill_diagonal(coupled, False)
        dev = np.asarray(deviating, bool)
        self.coupled_pending[:] = dev & np.any(coupled[:, dev], axis=1)

    def judge_together(self, relevant: np.ndarray) -> None:
        """Mark, per mode and quantity, the deviations that come together with the mode's gain deviation
        (``relevant``: (K, 3) bool, relevant deviations): while the recursion re-converges after an abrupt change it
        splits the move between them (a gain drop read as a damping rise: the resonance peak ``b0/(2 zeta)`` moves
        first; on a few reference lines a gain change read as a frequency shift); with an identified reference, only
        a joint fit of the data after the change says which of them changed. A frequency shift with a damping swing
        alone keeps the recursion's confirmation (the swing is the shift's signature, not the converse)."""
        rel = np.asarray(relevant, bool)
        gain_and_other = rel[:, 2] & (rel[:, 0] | rel[:, 1])
        self.together_pending[:] = (self.reference_identified & gain_and_other)[:, None] & rel

    def judge_travel(self, travelling: np.ndarray) -> None:
        """Mark the damping and gain deviations under test whose estimate still travels (``travelling``: (K, 3)
        bool). The recursion confirms them only once they hold still, which after a large damping change takes it
        several memory lengths; with an identified reference, two consecutive joint fits of the data after the change
        that support the deviation confirm it sooner (the joint fit names the new level, not a swing)."""
        suspect = np.array([[tst.state == "suspect" for tst in row] for row in self.tests], dtype=bool)
        suspect[:, 0] = False
        self.travel_pending[:] = self.reference_identified & suspect & np.asarray(travelling, bool)

    def judge_peak(self, t: float, change: np.ndarray) -> None:
        """Follow each mode's resonance-peak change at ``t`` (``change`` (K,): relevant and significant while its gain
        and damping tests are quiet, else NaN, :func:`.deviations.peak_moved`): such a mode's damping and gain need
        the joint check, which names the one that changed."""
        moved = np.isfinite(change)
        self.peak_since = np.where(moved, np.where(np.isnan(self.peak_since), t, self.peak_since), np.nan)
        self.peak_change = np.asarray(change, float).copy()

    def peak_unresolved(self) -> list[tuple[int, float, float]]:
        """(mode, relative change, since) of each peak change the joint check has not named."""
        return [(i, float(self.peak_change[i]), float(self.peak_since[i])) for i in range(self.setup.K)
                if np.isfinite(self.peak_change[i]) and not any(self.tests[i][q].state == "fault" for q in (1, 2))]

    def _second_quantity(self, i: int, q: int) -> bool:
        """(mode ``i``, quantity ``q``) deviates beside a fault of another quantity of the same mode: the recursion's
        split between the mode's quantities re-converges after the change (a gain drop read as a damping rise: the
        resonance peak ``b0/(2 zeta)`` moves first), so only a joint fit of the data after it can name a second one."""
        return self.reference_identified and any(e.mode == i + 1 and e.quantity != QUANTITIES[q]
                                                 for e in self.tests.open_events)

    def _second_pending(self) -> np.ndarray:
        """(K,) bool: modes with a suspected deviation beside a fault of another of their quantities."""
        return np.array([any(tst.state == "suspect" and self._second_quantity(i, q) for q, tst in enumerate(row))
                         for i, row in enumerate(self.tests)], dtype=bool)

    def _split_open(self, i: int, q: int) -> bool:
        """The recursion's split is open for (mode ``i``, quantity ``q``) whatever the excitation: a joint check
        refused this deviation, the model-order check flags the model (a model that misfits the data moves a change
        of one mode into another: a 51 Hz gain rise read as a 1.7 Hz frequency rise), the mode deviates beside a
        coupled mode, it deviates together with the mode's gain, or another of its quantities is at fault."""
        return (self.model_flagged or bool(self.refused[i, q]) or bool(self.coupled_pending[i])
                or bool(self.together_pending[i, q]) or (q > 0 and math.isfinite(self.peak_change[i]))
                or self._second_quantity(i, q))

    def _beyond_armed(self) -> bool:
        """A joint check is needed beyond the armed modes and the stress: a split is open somewhere, or a joint
        event is open (the checks hold and clear it). A flagged model alone needs none: no fit confirms anything."""
        return bool(self.refused.any() or self.coupled_pending.any() or self.travel_pending.any()
                    or self.together_pending.any() or np.isfinite(self.peak_change).any()
                    or self._second_pending().any()) or self._joint_events_open()

    def _joint_events_open(self) -> bool:
        return any(tst.state == "fault" and tst.by_joint for row in self.tests for tst in row)

    def arm(self, verdict: JointVerdict) -> None:
        """The baseline window's joint fit: arm the modes with some applicable quantity not identifiable jointly."""
        base = self.phases.baseline
        if base is not None and base.source == "given":
            # the user's baseline is the reference; the fit says what the excitation identifies
            with np.errstate(divide="ignore", invalid="ignore"):
                peak = np.hypot(base.std[:, 1] / np.abs(base.value[:, 1]), base.std[:, 2] / np.abs(base.value[:, 2]))
            verdict = replace(verdict, value=base.value.copy(), std=base.std.copy(), peak_own_std=peak)
        self.latest = self.reference = verdict
        if not verdict.converged:
            # the baseline window does not identify the joint model (narrow excitation: fewer lines than
            # parameters): the recursion's split between the modes is not evidence, every mode needs the joint
            # check's support, which no fit gives until a quiet window identifies the model (JointChecker.step)
            self.armed_modes = np.ones(self.setup.K, dtype=bool)
            return
        app = applicable_mask(self.setup.structures)
        self.armed_modes = verdict.armed_modes(app)

    def basis(self) -> tuple[np.ndarray, np.ndarray]:
        """(value, std) a joint fit is compared with: the converged reference fit, else the baseline (while the
        reference is pending no fit confirms anything: :meth:`apply`)."""
        ref = self.reference
        if ref is not None and ref.converged:
            return ref.value, ref.std
        base = self.phases.baseline
        assert base is not None
        return base.value, base.std

    def due(self, t: float, last_check: float) -> bool:
        """Whether a joint check is due: every quarter memory while a test deviates or a joint event is open, else
        every two memory lengths."""
        needed = self.armed or (self.stress.anomaly_since is not None and self.reference is not None) or \
            self._beyond_armed()
        if not needed or self.phases.phase != "monitoring":
            return False
        busy = any(tst.state != "ok" for row in self.tests for tst in row) or bool(np.any(self.streak))
        period = (0.25 if busy else 2.0) * float(self.setup.memory_s.max())
        return math.isnan(last_check) or t - last_check >= period

    def apply(self, t: float, verdict: JointVerdict, held: bool) -> FaultUpdate:
        """One joint check while monitoring (not ``held``): confirm what two consecutive checks support, clear what
        two no longer support. An unconverged fit judges nothing but breaks the streaks (open events are kept)."""
        out = FaultUpdate()
        self.latest = verdict
        needed = self.armed or self.stress.anomaly_since is not None or self._beyond_armed()
        if needed and not verdict.converged and not held:
            # a check that found no fit breaks the chain of consecutive support: fits that alternate between two
            # optima (a mode the window does not identify jumping between them) support what the other optimum moved
            self.streak[:] = 0
        if not (needed and verdict.converged) or self.phases.baseline is None or held:
            return out
        if verdict.blended:
            # the window holds a change (or the noise changed): its fit is a blend of two plants and neither
            # supports nor refuses anything; consecutive support starts again
            self.streak[:] = 0
            return out
        if self.reference_pending:
            # the baseline window did not identify the joint model: a later fit that converges on the changed
            # plant has nothing trustworthy to be compared with, so it confirms nothing (the deviation stays blind)
            self.streak[:] = 0
            return out
        sup = verdict.supported
        if self.stress.anomaly_since is not None:
            app = applicable_mask(self.setup.structures)
            moved = {int(i) for i in np.flatnonzero(np.any((sup != 0) & app, axis=1))}
            if len(moved) >= 2 and not any(e.mode - 1 in moved for e in self.tests.open_events):
                # after an abrupt change of the output, a joint fit that moves several modes at once does not
                # point at one structural change (a sensor bias or drift refits every mode): nothing is confirmed
                self.streak[:] = 0
                self.several_modes_t = t
                return out
        same = (sup != 0) & (np.sign(self.streak) == sup)
        self.streak = np.where(same, self.streak + sup, sup)
        self._note_refusals(sup, verdict.identifiable)
        for i in range(self.setup.K):
            for q in range(3):
                self._judge(t, i, q, verdict, out)
        return out

    def _note_refusals(self, support: np.ndarray, identifiable: np.ndarray) -> None:
        """Mark the deviations under test that this converged joint check does not support: those that needed it,
        and any other it identifies (a 58 Hz mode's gain drop absorbed by the recursion into a broad 15 Hz
        neighbour's gain, which the joint fit held unchanged, was confirmed by the recursion alone)."""
        for i, row in enumerate(self.tests):
            for q, tst in enumerate(row):
                if tst.state == "suspect" and support[i, q] != tst.direction and (
                        self.needed(i, q) or bool(identifiable[i, q])):
                    self.refused[i, q] = True

    def forget_refusals(self) -> None:
        """A refusal lasts while its deviation is under test (it ends when the deviation does)."""
        for i, row in enumerate(self.tests):
            for q, tst in enumerate(row):
                if tst.state != "suspect":
                    self.refused[i, q] = False

    def _judge(self, t: float, i: int, q: int, verdict: JointVerdict, out: FaultUpdate) -> None:
        """Hold or clear the joint event of (mode ``i``, quantity ``q``), or open one its streak supports."""
        test = self.tests[i][q]
        sup = verdict.supported
        if test.state == "fault" and test.by_joint:
            self._follow_event(t, test, int(sup[i, q]), float(verdict.value[i, q]), out)
            return
        if self.model_flagged:
            # the joint fit has the flagged model's structure: it misfits the data as the recursion does, and its
            # split between modes and quantities is no evidence either (a damping rise fitted as damping and gain
            # drops); the deviation stays blind
            return
        if test.state == "fault" or abs(self.streak[i, q]) < 2 or not self.setup.applicable(i, q) \
                or not (self.armed_modes[i] or self.stress.anomaly_since is not None
                        or self._split_open(i, q) or self.travel_pending[i, q]):   # the recursion alone decides
            return
        ref_value, ref_std = self.basis()
        sigma = math.hypot(float(verdict.std[i, q]), float(ref_std[i, q]))
        dev = float(verdict.value[i, q] - ref_value[i, q])
        onset = verdict.window_s[0] if math.isnan(test.since) else min(test.since, verdict.window_s[0])
        if test.state == "suspect" and test.direction == int(sup[i, q]):
            onset = min(onset, test.onset(test.direction))     # the recursion's estimate of when it began
        ev = test.open_joint(t, onset, int(sup[i, q]), float(ref_value[i, q]), float(verdict.value[i, q]),
                             dev / sigma if sigma > 0 else math.inf)
        out.opened.append(ev)
        self.tests.events.append(ev)

    @staticmethod
    def _follow_event(t: float, test: SequentialTest, support: int, value: float, out: FaultUpdate) -> None:
        """A joint event stays while the checks support its direction (its value follows the fit); it clears after
        two consecutive checks that do not."""
        assert test.event is not None      # the fault state always carries its open event
        if support == test.direction:
            test.joint_miss = 0
            test.event.value = value
            return
        test.joint_miss += 1
        if test.joint_miss >= 2:
            test.event.clear_time_s = t
            out.closed.append(test.event)
            test.event, test.state = None, "ok"
            test.reset(t)

    def to_dict(self) -> dict[str, Any]:
        return {"joint_armed_modes": self.armed_modes.tolist(),
                "joint": None if self.latest is None else self.latest.to_dict(),
                "joint_reference": None if self.reference is None else self.reference.to_dict(),
                "joint_streak": self.streak.tolist(), "joint_refused": self.refused.tolist(),
                "joint_peak_since": [None if math.isnan(v) else float(v) for v in self.peak_since]}

    def load(self, state: Mapping[str, Any]) -> None:
        """Restore :meth:`to_dict`'s items of a saved monitor state (a state with one ``joint_armed`` flag arms every
        mode alike)."""
        K = self.setup.K
        armed = state.get("joint_armed_modes", [bool(state.get("joint_armed", False))] * K)
        self.armed_modes = np.asarray(armed, dtype=bool).reshape(K)
        self.latest = None if state.get("joint") is None else JointVerdict.from_dict(state["joint"])
        ref = state.get("joint_reference")
        self.reference = None if ref is None else JointVerdict.from_dict(ref)
        self.streak = np.asarray(state.get("joint_streak", np.zeros((K, 3))), dtype=int)
        self.refused = np.asarray(state.get("joint_refused", np.zeros((K, 3))), dtype=bool).reshape(K, 3)
        since = state.get("joint_peak_since") or [None] * K
        self.peak_since = np.array([math.nan if v is None else float(v) for v in since], dtype=float).reshape(K)
