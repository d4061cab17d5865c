"""What the monitor pipeline publishes at one output instant (:class:`Report`) and the counts it keeps.

A :class:`Report` is the one record the node's ``~/modes`` and ``/diagnostics``, and the offline CSVs, are made from
(docs/INTERFACE.md); :class:`Counters` are the data-path counts every report's health carries.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..diagnosis.decision import ModeDecision
from ..diagnosis.faults import FaultEvent, Level
from ..estimation.estimator import EstimatorHealth
from ..vocabulary import BASELINE_FIELDS, FLAG_FIELDS, MODE_FIELDS, QUANTITIES


def modes_text(modal: np.ndarray) -> str:
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
    decisions: list[ModeDecision] = field(default_factory=list)   # per mode: state, reason, holds
                                                                  # (core/diagnosis/decision.py)

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
class Counters:
    """Data-path counts since the run began (health keys of the same names, docs/INTERFACE.md)."""

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
