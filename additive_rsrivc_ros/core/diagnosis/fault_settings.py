"""The fault logic's configuration: diagnostic levels, the ``faults.*`` thresholds and what the monitor's parts share.

:class:`FaultSettings` holds the thresholds (one field per ``faults.*`` row of core/params.py); :class:`FaultSetup`
adds the modes (one memory length and structure each) and the times derived from them (settling, baseline window,
clear time, CUSUM run length, S1-S4 of :mod:`.faults`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from enum import IntEnum
from typing import Any

import numpy as np

from ..model import SubmodelStructure
from ..params import from_param, settings_from_params
from ..vocabulary import BASELINE_KEYS, QUANTITIES


class Level(IntEnum):
    """diagnostic_msgs/DiagnosticStatus levels."""

    OK = 0
    WARN = 1
    ERROR = 2
    STALE = 3


class FaultConfigError(ValueError):
    """Fault settings or a given baseline that cannot be used (one-line message)."""


@dataclass(frozen=True)
class FaultSettings:
    """Thresholds of the fault logic: each field is filled from the ``faults.*`` row(s) it names (core/params.py,
    which holds their defaults, ranges and descriptions)."""

    enabled: bool = from_param("faults.enabled")
    settle_memory_lengths: float = from_param("faults.settle_memory_lengths")
    settle_max_memory_lengths: float = from_param("faults.settle_max_memory_lengths")
    baseline_duration_s: float = from_param("faults.baseline_duration_s")
    baseline_memory_lengths: float = from_param("faults.baseline_memory_lengths")
    # per quantity (BASELINE_KEYS), per mode; empty: learn the baseline
    baseline_value: tuple[tuple[float, ...], ...] = from_param(*(f"faults.baseline.{k}" for k in BASELINE_KEYS))
    baseline_std: tuple[tuple[float, ...], ...] = from_param(*(f"faults.baseline.{k}_std" for k in BASELINE_KEYS))
    min_change: tuple[float, float, float] = from_param(*(f"faults.min_change.{q}" for q in QUANTITIES))
    relevance_spread_factor: float = from_param("faults.min_change.spread_factor")
    cusum_reference_sigma: float = from_param("faults.cusum.reference_sigma")
    cusum_threshold: float = from_param("faults.cusum.threshold")
    cusum_false_alarm_interval_days: float = from_param("faults.cusum.false_alarm_interval_days")
    persistence_s: float = from_param("faults.persistence_s")
    persistence_memory_lengths: float = from_param("faults.persistence_memory_lengths")
    fast_memory_fraction: float = from_param("faults.fast.memory_fraction")
    fast_memory_lengths: float = from_param("faults.fast.memory_lengths")
    clear_s: float = from_param("faults.clear_s")
    clear_memory_lengths: float = from_param("faults.clear_memory_lengths")
    clear_fraction: float = from_param("faults.clear_fraction")
    health_holdoff_memory_lengths: float = from_param("faults.health.holdoff_memory_lengths")
    health_holdoff_min_s: float = from_param("faults.health.holdoff_min_s")
    health_max_condition: float = from_param("faults.health.max_condition")
    health_max_projection_fraction: float = from_param("faults.health.max_projection_fraction")
    health_residual_jump_ratio: float = from_param("faults.health.residual_jump_ratio")
    health_max_relative_std: float = from_param("faults.health.max_relative_std")
    health_max_parameter_ratio: float = from_param("faults.health.max_parameter_ratio")
    health_stuck_s: float = from_param("faults.health.stuck_s")
    health_stuck_min_samples: int = from_param("faults.health.stuck_min_samples")
    health_gap_tolerance: float = from_param("faults.health.gap_tolerance")
    health_repeated_output_is_missing: bool = from_param("faults.health.repeated_output_is_missing")
    health_max_repeated_fraction: float = from_param("faults.health.max_repeated_fraction")

    @classmethod
    def from_params(cls, p: Mapping[str, Any]) -> FaultSettings:
        """Build from flat ``faults.*`` parameters (missing names keep their defaults) and check them."""
        s = settings_from_params(cls, p)
        s.check()
        return s

    def check(self, n_modes: int | None = None) -> None:
        """Raise :class:`FaultConfigError` on inconsistent values (ranges are also in FAULT_PARAMS)."""
        if not all(v > 0 for v in self.min_change):
            raise FaultConfigError("faults.min_change.* must be > 0")
        if self.cusum_threshold < 0 or self.cusum_reference_sigma < 0 or not self.cusum_false_alarm_interval_days > 0:
            raise FaultConfigError("faults.cusum.threshold and faults.cusum.reference_sigma must be >= 0 and "
                                   "faults.cusum.false_alarm_interval_days > 0")
        if not 0.0 < self.clear_fraction < 1.0:
            raise FaultConfigError("faults.clear_fraction must be in (0, 1)")
        given = [len(v) for v in self.baseline_value]
        if any(given) and n_modes is not None:
            for key, n in zip(BASELINE_KEYS, given, strict=True):
                if n != n_modes:
                    raise FaultConfigError(f"faults.baseline.{key} has {n} entries but there are {n_modes} modes "
                                           "(give all three lists, or none to learn the baseline)")
            for key, v in zip(BASELINE_KEYS, self.baseline_std, strict=True):
                if len(v) not in (0, n_modes):
                    raise FaultConfigError(f"faults.baseline.{key}_std has {len(v)} entries, expected {n_modes} or 0")
                if any(not (x >= 0 and math.isfinite(x)) for x in v):
                    raise FaultConfigError(f"faults.baseline.{key}_std must be finite and >= 0")

    @property
    def has_given_baseline(self) -> bool:
        return any(len(v) for v in self.baseline_value)


@dataclass
class FaultSetup:
    """The modes the fault logic watches (one memory length and structure each) and its thresholds, shared by the
    monitor's parts; the monitor replaces ``memory_s`` and ``settings`` at runtime, the parts read them here."""

    memory_s: np.ndarray
    structures: list[SubmodelStructure]
    settings: FaultSettings

    @classmethod
    def of(cls, memory_s: Sequence[float] | np.ndarray, settings: FaultSettings | None,
           structures: Sequence[SubmodelStructure] | None) -> FaultSetup:
        """Check and build (:class:`FaultConfigError` on memories, structures or settings that do not fit)."""
        memory = np.asarray(memory_s, dtype=float)
        if memory.ndim != 1 or memory.size == 0 or not np.all(memory > 0):
            raise FaultConfigError("memory_s must list one positive memory length per mode")
        K = memory.size
        structs = list(structures) if structures is not None else [SubmodelStructure()] * K
        if len(structs) != K:
            raise FaultConfigError(f"{len(structs)} structures for {K} modes")
        s = settings or FaultSettings()
        s.check(K)
        return cls(memory, structs, s)

    @property
    def K(self) -> int:
        """Number of modes."""
        return int(self.memory_s.size)

    @property
    def settle_s(self) -> float:
        return self.settings.settle_memory_lengths * float(self.memory_s.max())

    @property
    def baseline_window_s(self) -> float:
        s = self.settings
        return s.baseline_duration_s if s.baseline_duration_s > 0 else s.baseline_memory_lengths * float(
            self.memory_s.max())

    def clear_time_s(self, i: int) -> float:
        s = self.settings
        return max(s.clear_s, s.clear_memory_lengths * float(self.memory_s[i]))

    def arl0_samples(self, i: int) -> float:
        """Target in-control run length of one CUSUM side in independent estimates (S1: one per 2 T_i)."""
        return self.settings.cusum_false_alarm_interval_days * 86400.0 / (2.0 * float(self.memory_s[i]))

    def applicable(self, i: int, q: int) -> bool:
        """Frequency and damping are tested only for second-order modes (a rigid body has only a gain)."""
        return q == 2 or self.structures[i].n == 2
