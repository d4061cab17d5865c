"""Runtime parameter changes of the monitor pipeline, each checked into the value it takes (``faults.*``,
``modes.memory_s``, ``publish_rate_hz``; the node's ``RuntimeChanges``). A bad value raises :class:`PipelineError`
with one line before anything of the pipeline changed.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from ..diagnosis.faults import FaultMonitor, FaultSettings
from ..estimation.estimator import MonitorSettings
from .report_record import PipelineError


def fault_settings(changes: Mapping[str, Any], faults: FaultMonitor | None, given: MonitorSettings,
                   earlier: Mapping[str, Any]) -> FaultSettings:
    """The fault settings after the ``faults.*`` ``changes``: the fault monitor's, updated in place, or while the modes
    are not found yet the ones it will start with (the configured parameters, the ``earlier`` changes, these)."""
    try:
        if faults is None:
            new = FaultSettings.from_params({**given.params, **earlier, **changes})
            new.check(given.mode_count or None)
            return new
        faults.update_settings(changes)
        return faults.settings
    except ValueError as exc:
        raise PipelineError(str(exc)) from None


def mode_memories(value: Any, K: int, rate: float) -> np.ndarray:
    """``modes.memory_s`` for the K known modes (one value for all, as in the params file), each at least two
    samples."""
    mem = np.asarray(value, dtype=float).ravel()
    if mem.size == 1:                 # one value for all modes, as in the params file
        mem = np.full(K, float(mem[0]))
    if mem.shape != (K,) or not np.all(mem * rate >= 2.0):
        raise PipelineError(f"modes.memory_s must list {K} memories of at least two samples")
    return mem


def given_memories(value: Any, rate: float) -> list[float]:
    """``modes.memory_s`` changed before the modes are known: the memories the found modes will get."""
    mem = [float(v) for v in np.atleast_1d(np.asarray(value, dtype=float))]
    if not mem or not all(m * rate >= 2.0 for m in mem):
        raise PipelineError("modes.memory_s must list memories of at least two samples")
    return mem


def publish_period(rate_hz: Any) -> float:
    """The report period for ``publish_rate_hz``."""
    rate = float(rate_hz)
    if not (rate > 0 and math.isfinite(rate)):
        raise PipelineError("publish_rate_hz must be > 0")
    return 1.0 / rate
