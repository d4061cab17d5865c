"""The recent modal estimates of the fault monitor: has the estimate settled, or is it still travelling?

The monitor remembers the estimates of about one and a half longest memories. :meth:`EstimateHistory.converged`
(S2 of :mod:`.faults`: a baseline needs a converged estimate) and :meth:`EstimateHistory.moving` (damping and gain
are confirmed only once they and the mode's frequency hold still) compare the latest estimate with an older one.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from typing import Any

import numpy as np

from .fault_settings import FaultSetup


class EstimateHistory:
    """``(t, modal)`` of the recent estimates (``entries``, oldest first), at least 1.5 longest memories back."""

    def __init__(self, setup: FaultSetup) -> None:
        self.setup = setup
        self.entries: deque[tuple[float, np.ndarray]] = deque()

    def remember(self, t: float, modal: np.ndarray) -> None:
        self.entries.append((t, modal.copy()))
        horizon = 1.5 * float(self.setup.memory_s.max())
        while len(self.entries) > 2 and t - self.entries[1][0] >= horizon:
            self.entries.popleft()

    def ago(self, t: float, lag_s: float) -> np.ndarray | None:
        """The latest remembered estimate at least ``lag_s`` before ``t`` (None if the history is shorter)."""
        for tp, m in reversed(self.entries):
            if tp <= t - lag_s:
                return m
        return None

    def converged(self, t: float, modal: np.ndarray) -> bool:
        """The estimate has settled: over the last memory length of each mode no estimate moved by more than 3
        reported std (S2 needs a converged estimate; a sluggish start from a small P(0) still drifts)."""
        setup = self.setup
        for i in range(setup.K):
            then = self.ago(t, float(setup.memory_s[i]))
            if then is None:
                return False
            for q in range(3):
                if not setup.applicable(i, q):
                    continue
                x0, s0, x1, s1 = then[i, q], then[i, 3 + q], modal[i, q], modal[i, 3 + q]
                if not all(math.isfinite(v) for v in (x0, s0, x1, s1)):
                    return False
                if abs(x1 - x0) > 3.0 * s1:
                    return False
        return True

    def moving(self, t: float, modal: np.ndarray, rho: np.ndarray, memory_now: Sequence[float],
               lookback: float = 1.0) -> np.ndarray:
        """(K, 3) bool: over the last ``lookback`` memory lengths (``memory_now``: each mode's memory as the
        estimator uses it now, S7) the estimate moved by more than three of its std and a tenth of the relevant
        change ``rho``, i.e. it is still travelling."""
        out = np.zeros((self.setup.K, 3), dtype=bool)
        for i in range(self.setup.K):
            then = self.ago(t, lookback * memory_now[i])
            if then is None:
                continue
            for q in range(3):
                if not self.setup.applicable(i, q):
                    continue
                step = abs(modal[i, q] - then[i, q])
                tol = max(3.0 * float(modal[i, 3 + q]), 0.1 * float(rho[i, q]) * abs(float(modal[i, q])))
                out[i, q] = bool(math.isfinite(step) and step > tol)
        return out

    def to_list(self) -> list[list[Any]]:
        return [[tp, m.tolist()] for tp, m in self.entries]

    def load(self, entries: Sequence[Sequence[Any]]) -> None:
        self.entries = deque((float(tp), np.asarray(m, float)) for tp, m in entries)
