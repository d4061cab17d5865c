"""The health part of a :class:`.report_record.Report`: what the stream aligner, the fault monitor and the joint
check found, in the keys of docs/INTERFACE.md. The pipeline decides; these functions only say it.

Every finding that is not a hold but must be seen (a re-alignment, an output anomaly, an untrusted baseline, a
structural change whose split between gain and damping is open) raises the health level to at least WARN and adds
one reason line.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..diagnosis.decision import Hold, ModeDecision, decide
from ..diagnosis.faults import FaultMonitor, HealthStatus, Level
from ..diagnosis.joint_check import applicable_mask
from ..input.alignment import AlignmentStats, InvariantAligner
from ..model import SubmodelStructure
from ..vocabulary import ALIGN_APPROXIMATE_RELATIVE, QUANTITIES

ALIGN_NOTE_HOLD_S = 5.0             # a re-alignment stays in the health reasons this long (report time)
ALIGN_UNDECIDED_FRACTION = 0.5      # report when more than this fraction of a report period is undecidable


def _warn(health: dict[str, Any], line: str) -> None:
    """One reason line, and the level at least WARN."""
    health["reasons"].append(line)
    health["level"] = max(int(health["level"]), int(Level.WARN))
    health["ok"] = False


class AlignmentNotes:
    """What the stream aligner found, carried from the samples it released to the next reports."""

    def __init__(self) -> None:
        self.pending: list[str] = []          # re-alignments since the last report
        self.late = 0                         # samples that reached the estimator before their shift was found
        self._prev = (0, 0)                   # (samples_out, undecided) at the last report
        self._shown: tuple[str, float] | None = None   # last re-alignment note and its report time

    def absorb(self, stats: AlignmentStats) -> int:
        """Take the aligner's new findings; return how many samples newly reached the estimator misaligned."""
        self.pending += [msg for _, msg in stats.events]
        stats.events.clear()
        n_late = max(stats.late - self.late, 0)
        self.late = max(self.late, stats.late)
        return n_late

    def to_health(self, health: dict[str, Any], aligner: InvariantAligner | None, t_rep: float) -> None:
        """``health["alignment"]`` and the reasons since the last report (non-holding: corrected data are valid)."""
        if aligner is None:
            health["alignment"] = {"mode": "off"}
            return
        st = aligner.stats
        out0, und0 = self._prev
        n_out, n_und = st.samples_out - out0, st.undecided - und0
        self._prev = (st.samples_out, st.undecided)
        rel = st.relative_residual
        health["alignment"] = {"mode": "invariant", "verified": aligner.verified, **st.to_dict()}
        notes = []
        if self.pending:      # shown for ALIGN_NOTE_HOLD_S: a 1 Hz /diagnostics must not miss it
            self._shown = ("; ".join(self.pending) + " (corrected before estimation)"
                           if len(self.pending) < 4 else f"{len(self.pending)} re-alignments "
                           f"since t={t_rep:.1f} s (lost or repeated messages, corrected before estimation)", t_rep)
            self.pending = []
        if self._shown is not None and t_rep - self._shown[1] < ALIGN_NOTE_HOLD_S:
            notes.append(self._shown[0])
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


class BlindTime:
    """Since when the fault tests are held (blind), for the health's ``blind_since`` and its reason line."""

    def __init__(self) -> None:
        self.since: float | None = None

    def to_health(self, health: dict[str, Any], faults: FaultMonitor, initialized: bool, hold: bool,
                  t_rep: float) -> None:
        paused = faults.baseline is None and faults.learner.n > 0 and faults.learner.paused
        tests_on = initialized and (faults.phase in ("learning", "monitoring") or paused)
        if hold and tests_on:
            if self.since is None:
                self.since = t_rep
            health["reasons"].append(f"fault tests held (blind) since t={self.since:.1f} s" + (
                f"; baseline window paused ({faults.learner.elapsed_s:.1f} s learned, kept)" if paused else ""))
        elif not hold:
            self.since = None
        health["blind_since"] = self.since


def anomaly_reason(health: dict[str, Any], faults: FaultMonitor | None, K: int, t_rep: float) -> None:
    """While an output anomaly restricts confirmation, say until when and what is judged after it."""
    if faults is None or faults.anomaly_since is None:
        return
    until = max(faults.restricted_until(i) or t_rep for i in range(K))
    if t_rep < until:
        _warn(health, f"output anomaly since t={faults.anomaly_since:.1f} s (residual variance jump or projection "
                      f"storm): until t={until:.1f} s only a fault that began with it can be confirmed; after that "
                      "every persistent deviation is judged against the baseline")


def decisions(faults: FaultMonitor | None, status: HealthStatus, initialized: bool, K: int,
              no_model: str | None) -> list[ModeDecision]:
    """Each mode's decision state at this report (:mod:`.decision`): the one account of what the tests did."""
    if faults is None:
        return []
    holds = list(status.holds)
    if faults.phase == "learning" and not status.hold:
        holds = []          # holds scoped to one mode do not pause the baseline window (its spread shows them)
    why = ("cannot be named: the model-order check flags the model, and a model that misfits the data moves a change "
           "between modes and quantities" if faults.model_flagged else "awaits the joint check's support (the "
           "excitation or an abrupt change leaves the recursion's split between quantities open)")
    holds += [Hold("joint_check", f"a {QUANTITIES[q].replace('_', ' ')} deviation {why}", since, math.inf, (i,))
              for i, q, since in faults.awaiting_joint()]
    namer = ("the model-order check flags the model, so neither can be named" if faults.model_flagged else
             "the joint check names the one that changed")
    holds += [Hold("joint_check", f"the resonance peak gain/(2 damping) moved by {100 * change:+.1f} % while neither "
                   f"gain nor damping deviates enough on its own: {namer}", since, math.inf, (i,))
              for i, change, since in faults.peak_unresolved()]
    restricted = [faults.restricted_until(i) for i in range(K)]
    return decide(faults.phase, initialized, [[tst.state for tst in row] for row in faults.tests],
                  holds, restricted, no_model_reason=no_model or "initializing")


def fault_fields(faults: FaultMonitor | None) -> dict[str, Any]:
    """Baseline, flags, levels and directions of a report ((0, 3) while the modes are not known)."""
    if faults is None:
        return {"baseline": np.zeros((0, 3)), "baseline_std": np.zeros((0, 3)),
                "flags": np.zeros((0, 3), dtype=bool), "levels": np.zeros((0, 3), dtype=int), "directions": []}
    b, bs = faults.baseline_arrays()
    return {"baseline": b, "baseline_std": bs, "flags": faults.flags, "levels": faults.levels,
            "directions": faults.directions}


def baseline_health(health: dict[str, Any], faults: FaultMonitor) -> None:
    """Whether the baseline is trusted, and why not."""
    base = faults.baseline
    health["baseline_trusted"] = faults.baseline_trusted
    health["baseline_note"] = "" if base is None else base.note
    if base is not None and not base.trusted:
        _warn(health, base.note)


def identifiability_health(health: dict[str, Any], faults: FaultMonitor,
                           structures: Sequence[SubmodelStructure]) -> None:
    """What the excitation does not identify jointly, and resonance-peak changes (a change of a mode whose gain and
    damping cannot be told apart is reported here, never as a gain or damping event)."""
    verdict = faults.joint
    applicable = applicable_mask(structures)
    health["joint_check"] = None if verdict is None else {
        "armed": faults.joint_armed,
        "armed_modes": [int(i) + 1 for i in np.flatnonzero(faults.joint_armed_modes)],
        "coupling": verdict.coupling_lines(faults.joint_armed_modes, applicable),
        "t": verdict.t, "converged": verdict.converged,
        "not_identifiable": verdict.not_identifiable(applicable),
        "peak_changes": verdict.peak_lines()}
    t_multi = faults.joint_several_modes_t
    if math.isfinite(t_multi) and faults.anomaly_since is not None:
        _warn(health, f"output anomaly: the joint fit of the data after it moves several modes at once "
                      f"(t={t_multi:.1f} s), which no single structural change explains (a sensor bias "
                      "or drift?): not confirmed as a fault")
    if verdict is None or not faults.joint_armed:
        return
    peaks = verdict.peak_lines()
    if peaks:
        _warn(health, "structural change, gain and damping not separately identifiable from this excitation: "
                      + "; ".join(peaks))
