"""The seams of the monitor: what the pipeline needs of a recursive estimator and of its configuration.

* :class:`EstimatorHealth`: the typed health record a recursive estimator reports (counters, projections and
  rejections per mode, IV condition numbers, residual variance, ...). The health monitor
  (:class:`.faults.HealthMonitor`), the pipeline and the node read it by attribute; :meth:`EstimatorHealth.to_dict`
  gives the JSON form (``health.estimator`` in reports and ``summary.json``).
* :class:`RecursiveEstimator`: the protocol :class:`.recursive.RecursiveAdditiveSRIVC` implements and
  :class:`.pipeline.MonitorPipeline` calls (another estimator can be plugged in through its ``estimator_factory``).
* :class:`MonitorSettings`: the parts of the node's configuration (``config.MonitorConfig``) that ``core`` reads;
  ``core`` never imports ``config``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Any, Protocol, Self, runtime_checkable

import numpy as np

if TYPE_CHECKING:   # annotations only: scipy.signal (controller) is slow to import
    from ..controller import DiscreteController
    from ..input.alignment import AlignmentSettings
    from ..model import SubmodelStructure


@dataclass(frozen=True)
class EstimatorHealth:
    """What a recursive estimator reports about itself at one instant ([RA-SRIVC] Algorithm 2 safeguards, §4.7).

    Per-mode entries are tuples of length K. An estimator that does not report an item leaves its default (empty
    tuple, ``None``): the health monitor then skips the check that needs it.
    """

    samples: int = 0                   # samples seen
    updates: int = 0                   # parameter updates made (subsampled, skipped and held samples excluded)
    skipped_samples: int = 0           # non-finite or marked invalid: no update
    held_samples: int = 0              # during a re-prime hold
    hold_remaining: int = 0            # samples until the re-prime hold ends (> 0: filters re-priming)
    reprimes: int = 0                  # filter restarts (gaps marked by the caller and automatic ones)
    capped_updates: int = 0            # updates where the wind-up cap stopped dividing P by lambda
    projections: tuple[int, ...] = ()  # stability projections per mode ([RA-SRIVC] §4.7)
    rejected_updates: tuple[int, ...] = ()
    rejected_discretization: tuple[int, ...] = ()     # filter discretization not finite
    rejected_iv_denominator: tuple[int, ...] = ()     # IV denominator below its floor
    rejected_nonfinite_or_step: tuple[int, ...] = ()  # non-finite value, a2 = 0 or step too large
    nonfinite_instrument: int = 0      # samples whose instrument was not finite
    cond: tuple[float, ...] = ()       # condition number of the equilibrated IV matrix per mode
    covariance_problems: tuple[str, ...] = ()         # per mode "" or why its std is NaN (never reported as 0)
    information_relative_std: tuple[float, ...] = ()  # relative std of (f, gain) from sigma^2 P_bar per mode
    residual_var: float | None = None  # weighted mean squared output error (NaN before data)
    init_message: str = ""             # what the last initialization did

    def to_dict(self) -> dict[str, Any]:
        """The JSON form (the keys as written in ``health.estimator``; per-mode entries as lists)."""
        out = {}
        for f in fields(self):    # flat fields of numbers and strings: no deep copy (asdict) needed
            v = getattr(self, f.name)
            out[f.name] = list(v) if isinstance(v, tuple) else v
        return out


@runtime_checkable
class RecursiveEstimator(Protocol):
    """A streaming estimator of K modes as :class:`.pipeline.MonitorPipeline` drives it ([RA-SRIVC] Algorithm 2)."""

    def initialize(self, r: np.ndarray | None, u: np.ndarray, y: np.ndarray) -> Any:
        """Start on the first data (offline initialization, then filter priming)."""
        ...

    def update(self, r: np.ndarray | None, u: np.ndarray, y: np.ndarray, valid: np.ndarray | None = None, *,
               trace: bool = False) -> np.ndarray | None:
        """Process any number of samples; ``valid`` False marks samples to skip."""
        ...

    def mark_gap(self) -> None:
        """Data are missing: restart the filters and hold updates until they are primed again."""
        ...

    def modal(self) -> np.ndarray:
        """(K, 6): ``f_hz, zeta, gain`` and their std (NaN std when no valid covariance)."""
        ...

    def set_memory(self, memory_s: np.ndarray | Sequence[float] | float) -> None:
        """Forgetting memory per mode in seconds."""
        ...

    def closed_loop_max_pole(self) -> float:
        """Largest closed-loop pole modulus of the model with the controller (NaN in open loop)."""
        ...

    def get_state(self) -> dict[str, np.ndarray]:
        """Complete state (numpy arrays) for :meth:`set_state`."""
        ...

    def set_state(self, state: Mapping[str, np.ndarray]) -> None:
        """Restore a :meth:`get_state` snapshot."""
        ...

    @property
    def health(self) -> EstimatorHealth:
        """The current health record."""
        ...

    @property
    def thetas(self) -> list[np.ndarray]:
        """Latest parameter vector per mode ([RA-SRIVC] eq. 7 order; the model-order check reads it)."""
        ...


class ModeSettings(Protocol):
    """One mode's initial guess and memory (``config.ModeConfig``)."""

    @property
    def natural_frequency_hz(self) -> float: ...
    @property
    def damping_ratio(self) -> float: ...
    @property
    def gain(self) -> float: ...
    @property
    def integrators(self) -> int: ...
    @property
    def memory_s(self) -> float: ...

    @property
    def structure(self) -> SubmodelStructure: ...

    def theta0(self) -> np.ndarray: ...


class EstimatorSettings(Protocol):
    """Options of the recursive estimator (``config.EstimatorOptions``)."""

    @property
    def block_sweeps(self) -> int: ...
    @property
    def refinements(self) -> int: ...
    @property
    def stability_projection(self) -> bool: ...
    @property
    def output_subsampling(self) -> int: ...
    @property
    def p0_relative_a(self) -> float: ...
    @property
    def p0_relative_b(self) -> float: ...
    @property
    def p0_policy(self) -> str: ...
    @property
    def init_method(self) -> str: ...
    @property
    def init_max_iterations(self) -> int: ...
    @property
    def filter_smoothing(self) -> str: ...
    @property
    def init_warmup_s(self) -> float: ...
    @property
    def guess_spread(self) -> float: ...
    @property
    def order_check_memory_lengths(self) -> float: ...
    @property
    def order_check_relevance(self) -> float: ...


class SignalSettings(Protocol):
    """Topic and message type of one input signal (``config.SignalConfig``)."""

    @property
    def topic(self) -> str: ...
    @property
    def type(self) -> str: ...


class MonitorSettings(Protocol):
    """The configuration ``core`` reads (``config.MonitorConfig``, a frozen dataclass: ``dataclasses.replace``
    works on it)."""

    @property
    def loop_rate_hz(self) -> float: ...
    @property
    def closed_loop(self) -> bool: ...
    @property
    def controller(self) -> DiscreteController | None: ...
    @property
    def input_delay_samples(self) -> int: ...
    @property
    def modes(self) -> Sequence[ModeSettings]: ...
    @property
    def init_duration_s(self) -> float: ...
    @property
    def publish_rate_hz(self) -> float: ...
    @property
    def estimator(self) -> EstimatorSettings: ...
    @property
    def signals(self) -> Mapping[str, SignalSettings]: ...
    @property
    def params(self) -> dict[str, Any]: ...
    @property
    def mode_count(self) -> int: ...
    @property
    def max_mode_count(self) -> int: ...
    @property
    def frequency_range_hz(self) -> tuple[float, float] | None: ...
    @property
    def alignment(self) -> AlignmentSettings: ...
    @property
    def mode_memories_s(self) -> tuple[float, ...]: ...

    @property
    def K(self) -> int: ...
    @property
    def structures(self) -> list[SubmodelStructure]: ...
    @property
    def auto_modes(self) -> bool: ...

    def with_modes(self, modal: np.ndarray, integrators: list[int] | None = None) -> Self: ...

    def with_memory(self, memory_s: list[float]) -> Self: ...
