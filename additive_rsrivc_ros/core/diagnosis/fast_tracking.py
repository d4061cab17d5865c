"""Fast tracking (S7 of :mod:`.faults`): a detected change shortens the mode's memory for a while.

Variable forgetting, a known remedy of recursive identification ([RA-SRIVC] §4's forgetting made time-varying):
when a CUSUM of a mode crosses its threshold, the estimator uses ``faults.fast.memory_fraction`` of the mode's
memory for ``faults.fast.memory_lengths`` memory lengths, so the estimate reaches the changed plant in a fraction
of a memory instead of several. Off by default (``memory_fraction`` 1).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from .baseline import Baseline
from .fault_settings import FaultSetup
from .sequential_test import SequentialTest

FAST_DECAY_TIMES = 3.0
"""S7: a shortened memory keeps at least this many decay times of the mode (the estimator's own stable range)."""


class FastTracking:
    """Per mode: the end of its shortened memory (``until``) and whether this change has spent its shortening
    (``spent``: one per change, re-armed once every CUSUM of the mode is back at rest)."""

    def __init__(self, setup: FaultSetup) -> None:
        self.setup = setup
        self.until = np.full(setup.K, -math.inf)
        self.spent = np.zeros(setup.K, dtype=bool)

    def reset(self) -> None:
        """No shortened memory, none spent (a new baseline)."""
        self.until[:], self.spent[:] = -math.inf, False

    def memory_scale(self, t: float, baseline: Baseline | None) -> np.ndarray:
        """(K,) factor on each mode's configured memory the estimator should use at ``t`` (1, or
        ``faults.fast.memory_fraction`` while a detected change is being tracked, but never below
        ``FAST_DECAY_TIMES`` decay times ``1/(zeta omega)`` of the mode's ``baseline``: a memory shorter than the mode's
        own transient makes the estimate and its prefilters oscillate, see ``set_filter_policy`` of the estimator)."""
        setup = self.setup
        fast = t < self.until
        if not fast.any():
            return np.ones(setup.K)
        floor = np.zeros(setup.K)
        if baseline is not None:
            with np.errstate(divide="ignore", invalid="ignore"):
                decay = 1.0 / (baseline.value[:, 1] * 2.0 * math.pi * baseline.value[:, 0])
            second_order = np.array([s.n == 2 for s in setup.structures])
            floor = np.where(second_order & np.isfinite(decay), FAST_DECAY_TIMES * decay / setup.memory_s, 0.0)
        scale = np.minimum(1.0, np.maximum(setup.settings.fast_memory_fraction, floor))
        return np.where(fast, scale, 1.0)

    def effective_memory_s(self, i: int, t: float, baseline: Baseline | None) -> float:
        """Mode ``i``'s memory as the estimator uses it at ``t``: its estimates decorrelate, and a transient in them
        fades, within it."""
        return float(self.setup.memory_s[i]) * float(self.memory_scale(t, baseline)[i])

    def track(self, i: int, t: float, tests: Sequence[SequentialTest]) -> None:
        """When a CUSUM of mode ``i`` (its ``tests``) has crossed its threshold (a statistically sure change, about
        half the relevant size) and the mode has no open event, shorten the mode's memory from ``t`` on. The
        evidence of the tests is judged with the shortened memory meanwhile."""
        if self.spent[i]:
            if t >= self.until[i] and all(tst.g_up == 0.0 and tst.g_down == 0.0 for tst in tests):
                self.spent[i] = False          # the change is over (or was none): the next one may shorten
            return
        s = self.setup.settings
        if s.fast_memory_fraction >= 1.0:
            return
        if any(tst.state == "fault" for tst in tests):
            return
        if any(max(tst.g_up, tst.g_down) > tst.h for tst in tests if math.isfinite(tst.h)):
            self.until[i] = t + s.fast_memory_lengths * float(self.setup.memory_s[i])
            self.spent[i] = True

    def to_dict(self) -> dict[str, Any]:
        return {"fast_until": [x if math.isfinite(x) else None for x in self.until.tolist()],
                "fast_spent": self.spent.tolist()}

    def load(self, state: Mapping[str, Any]) -> None:
        K = self.setup.K
        until = state.get("fast_until") or [None] * K
        self.until = np.array([-math.inf if x is None else float(x) for x in until], dtype=float).reshape(K)
        self.spent = np.asarray(state.get("fast_spent", [False] * K), dtype=bool).reshape(K)
