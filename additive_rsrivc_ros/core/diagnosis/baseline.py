"""The per-mode reference of the fault tests (S1, S2 of :mod:`.faults`): a :class:`Baseline` and its learner.

The learner accumulates the estimate over a healthy window (paused by data problems) and returns its mean, the
fluctuation ``s_x = max(reported, empirical std)`` and the uncertainty ``s_b = s_x / sqrt(n_eff)`` with
``n_eff = W / (2 T)``; the window's first and last thirds are kept apart to detect a change spread over it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from .fault_settings import FaultConfigError, FaultSettings


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
