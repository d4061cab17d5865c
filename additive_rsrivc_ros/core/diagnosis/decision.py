"""The per-mode fault decision: one explicit state per mode, and holds that each have an owner, a reason and an end.

Every report gives each mode one :class:`ModeState` (blind, learning, monitoring, suspect, fault); the verdict,
``/diagnostics``, ``events.csv`` and the report read these states. A :class:`Hold` names its owner (the health issue
kind), its reason and its end (it lapses then unless its cause is seen again); a hold scoped to one mode (lost
excitation, an invalid covariance block) blinds that mode only, a data problem holds every mode, and an open event
is never held. Under estimator stress (a residual-variance jump: also the signature of a real abrupt change)
confirmation is restricted for a bounded window, never until the estimates return. The transitions are drawn and
explained in docs/DESIGN.md ("The fault decision").
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from enum import Enum
from typing import Any


class ModeState(str, Enum):  # noqa: UP042 (StrEnum needs Python 3.11; 3.10 is supported)
    """The decision state of one mode at one report."""

    BLIND = "blind"
    LEARNING = "learning"
    MONITORING = "monitoring"
    SUSPECT = "suspect"
    FAULT = "fault"


TESTED_STATES = (ModeState.MONITORING, ModeState.SUSPECT, ModeState.FAULT)
"""States in which the mode's fault tests ran (its time counts as monitored)."""


@dataclass(frozen=True)
class Hold:
    """A reason why fault tests do not run: who holds (``owner``: a health issue kind), why, since when, until when
    (``end_s``: lapses then unless the cause is seen again; ``inf``: the cause persists), and which modes
    (0-based; ``None``: every mode)."""

    owner: str
    reason: str
    since_s: float
    end_s: float
    modes: tuple[int, ...] | None = None

    def holds(self, i: int) -> bool:
        return self.modes is None or i in self.modes

    def to_dict(self) -> dict[str, Any]:
        return {"owner": self.owner, "reason": self.reason, "since_s": self.since_s,
                "end_s": self.end_s if math.isfinite(self.end_s) else None,
                "modes": None if self.modes is None else [i + 1 for i in self.modes]}

    @property
    def line(self) -> str:
        end = f"until t={self.end_s:.1f} s unless seen again" if math.isfinite(self.end_s) else "while it persists"
        return f"{self.reason} (held by {self.owner} since t={self.since_s:.1f} s, {end})"


@dataclass
class ModeDecision:
    """One mode's state at one report, with the reason and the holds behind it."""

    mode: int                   # 1-based
    state: ModeState
    reason: str = ""
    holds: list[Hold] = field(default_factory=list)
    restricted_until_s: float | None = None   # stress isolation window (see the module docstring)

    @property
    def tested(self) -> bool:
        return self.state in TESTED_STATES

    def to_dict(self) -> dict[str, Any]:
        return {"mode": self.mode, "state": self.state.value, "reason": self.reason,
                "holds": [h.to_dict() for h in self.holds], "restricted_until_s": self.restricted_until_s}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> ModeDecision:
        holds = [Hold(str(h["owner"]), str(h["reason"]), float(h["since_s"]),
                      math.inf if h.get("end_s") is None else float(h["end_s"]),
                      None if h.get("modes") is None else tuple(int(i) - 1 for i in h["modes"]))
                 for h in d.get("holds", [])]
        r = d.get("restricted_until_s")
        return cls(int(d["mode"]), ModeState(str(d["state"])), str(d.get("reason", "")), holds,
                   None if r is None else float(r))


def holds_on(holds: Sequence[Hold], i: int) -> list[Hold]:
    """The holds that blind mode ``i`` (0-based)."""
    return [h for h in holds if h.holds(i)]


def decide(phase: str, estimating: bool, test_states: Sequence[Sequence[str]], holds: Sequence[Hold],
           restricted_until_s: Sequence[float | None], *, no_model_reason: str = "") -> list[ModeDecision]:
    """Each mode's :class:`ModeDecision` from the monitor's phase, its tests' states (``ok | suspect | fault`` per
    quantity) and the holds: an open event is FAULT whatever holds; a held mode is BLIND with the holds' reasons;
    otherwise the phase (settling: BLIND, learning: LEARNING) or the tests decide."""
    out = []
    for i, row in enumerate(test_states):
        mine = holds_on(holds, i)
        restricted = restricted_until_s[i] if i < len(restricted_until_s) else None
        if not estimating:
            out.append(ModeDecision(i + 1, ModeState.BLIND, no_model_reason or "no valid model", mine))
        elif "fault" in row:
            out.append(ModeDecision(i + 1, ModeState.FAULT, "confirmed fault open", mine, restricted))
        elif mine:
            out.append(ModeDecision(i + 1, ModeState.BLIND, "; ".join(h.reason for h in mine), mine))
        elif phase in ("waiting", "settling", "initializing"):
            out.append(ModeDecision(i + 1, ModeState.BLIND, "settling: estimator converging before the baseline"))
        elif phase == "learning":
            out.append(ModeDecision(i + 1, ModeState.LEARNING, "learning the baseline"))
        elif "suspect" in row:
            out.append(ModeDecision(i + 1, ModeState.SUSPECT, "deviation under test", [], restricted))
        else:
            out.append(ModeDecision(i + 1, ModeState.MONITORING, "", [], restricted))
    return out
