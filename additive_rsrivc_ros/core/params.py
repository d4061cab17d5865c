"""The rows the numerical core is configured by, and the generic bridge from rows to settings dataclasses.

Every parameter is declared once, as a :class:`Param` row: dotted name, ROS type, default, description, range,
choices and whether a change needs a restart. The rows the core reads (``estimator.*``: :class:`EstimatorOptions`,
``faults.*``: ``core.fault_settings.FaultSettings``) live here because ``core/`` must not import the ROS-side
``config.py``; ``config.py`` adds the plant, signal, alignment and node rows, loads params YAML and renders
config/template.yaml and the README table from all rows.

A settings dataclass names, per field, the row(s) that fill it with :func:`from_param`, which also takes the
field's default from the row. :func:`settings_from_params` builds a dataclass from flat parameters and
:func:`settings_as_params` goes back: no field<->name map or default is written twice.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import Field, dataclass, field, fields
from typing import Any, TypeVar

PARAM_TYPES = ("bool", "int", "double", "string", "bool[]", "int[]", "double[]", "string[]")
DEFAULT_MEMORY_S = 10.0
"""A mode's forgetting memory when ``modes.memory_s`` is empty (the row's documented default)."""


@dataclass(frozen=True)
class Param:
    """One parameter: name (dotted), type, default, description and validity range."""

    name: str
    type: str
    default: Any
    description: str
    min: float | None = None
    max: float | None = None
    read_only: bool = False  # True: changing it needs a restart (re-initialization)
    choices: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if self.type not in PARAM_TYPES:
            raise ValueError(f"{self.name}: unknown type {self.type}")


# Recursive estimator and its offline initialization ([RA-SRIVC] Algorithm 2): fill EstimatorOptions.
ESTIMATOR_PARAMS: list[Param] = [
    Param("estimator.block_sweeps", "int", 1, "M_l: block-coordinate sweeps over the modes per sample.", 1, 20,
          True),
    Param("estimator.refinements", "int", 0, "M_s: SRIVC refinements per mode and sweep.", 0, 20, True),
    Param("estimator.stability_projection", "bool", True, "Reflect right-half-plane roots of A_i ([RA-SRIVC] §4.7).",
          read_only=True),
    Param("estimator.output_subsampling", "int", 1, "Update the estimate every n-th sample; all inputs are "
          "still filtered ([RA-SRIVC] §4.7).", 1, 1000, True),
    Param("estimator.p0_relative_a", "double", 0.016, "P(0) of a denominator coefficient relative to its "
          "square (1e-3/0.25^2: the paper's P(0) of its mode 1).", 1e-12, 1e3, True),
    Param("estimator.p0_relative_b", "double", 1.1e-6, "P(0) of a numerator coefficient relative to its "
          "square (1e-5/3^2: the paper's P(0) of its mode 1).", 1e-12, 1e3, True),
    Param("estimator.p0_policy", "string", "information", "P(0) after the offline initialization: 'information' "
          "(the initialization record's IV information weighted like the recursion, so the reported uncertainty and "
          "the adaptation gain start at their steady level) or 'relative' (p0_relative_a/b; also the fallback "
          "when the guesses are used).", read_only=True, choices=("information", "relative")),
    Param("estimator.init_method", "string", "auto", "Offline initialization: auto (additive-clsrivc in closed "
          "loop, additive-srivc in open loop), or one of the rsrivc_identify methods, or none (use the "
          "guesses as they are).", read_only=True,
          choices=("auto", "none", "additive-clsrivc", "additive-srivc", "bcd-srivc", "srivc", "clsrivc")),
    Param("estimator.filter_smoothing", "string", "auto", "Prefilter denominator from the estimate (off: [RA-SRIVC] "
          "Algorithm 2 as printed) or smoothed over one period of the mode (on); auto: only for modes whose memory is "
          "shorter than 3 decay times 1/(zeta omega), where the carried filter states ([RA-SRIVC] Remark 4.4) "
          "otherwise make the estimate oscillate.", read_only=True, choices=("auto", "on", "off")),
    Param("estimator.init_warmup_s", "double", -1.0, "Seconds at the start of the initialization data that only "
          "warm up the offline filters (left out of the fit); -1: automatic (none, unless the fit's output error "
          "starts with the plant's free response, i.e. the data start in motion: then 5 decay times of the slowest "
          "mode).", -1.0, 1e5, True),
    Param("estimator.init_max_iterations", "int", 30, "Iteration limit of the offline initialization.", 1, 1000,
          True),
    Param("estimator.guess_spread", "double", 0.1, "Relative standard deviation of the mode guesses taken as a "
          "prior by the offline initialization: its start is the posterior of the guesses and the fit (the fit's "
          "joint covariance), so the guesses are kept where the initialization data do not inform (a mode the "
          "excitation does not reach). 0: no prior (the fit replaces the guesses when it explains the data better). "
          "Modes found from the data carry no prior.", 0.0, 10.0, True),
    Param("estimator.order_check_memory_lengths", "double", 4.0, "Model-order check "
          "(core/identification/adequacy.py): on this many "
          "(longest) memory lengths of contiguous data after the initialization, once per run, the modelled modes "
          "are refitted offline with the strongest unmodelled resonance of the FRF misfit added; if that moves a "
          "modelled quantity relevantly, health warns 'model order too low' (never a structural fault). 0: off.",
          0.0, 1000.0, True),
    Param("estimator.order_check_relevance", "double", 0.25, "The model-order check warns when an unmodelled "
          "resonance moves a modelled natural frequency, damping or gain by more than this fraction of its "
          "faults.min_change.* (and by more than 3 standard deviations).", 0.0, 100.0, True),
]

# Fault diagnosis and estimator health (core/diagnosis/faults.py, core/diagnosis/health.py): fill
# core.fault_settings.FaultSettings.
FAULT_PARAMS: list[Param] = [
    Param("faults.enabled", "bool", True, "Run the structural fault tests (estimation and health run regardless)."),
    Param("faults.settle_memory_lengths", "double", 3.0, "Wait this many (longest) memory lengths after the "
          "recursion starts before the baseline window or the tests begin.", 0.0, 1000.0),
    Param("faults.settle_max_memory_lengths", "double", 30.0, "Start the baseline window after this many "
          "(longest) memory lengths even if the estimate has not converged (std still growing or estimate "
          "still moving).", 0.0, 1e5),
    Param("faults.baseline_duration_s", "double", 0.0, "Length of the healthy window the baseline is learned "
          "over (s); 0: faults.baseline_memory_lengths x the longest memory.", 0.0, 1e7),
    Param("faults.baseline_memory_lengths", "double", 5.0, "Baseline window in (longest) memory lengths when "
          "faults.baseline_duration_s is 0.", 0.5, 1000.0),
    *[Param(f"faults.baseline.{_k}", "double[]", [], f"Given baseline {_k} per mode (empty: learn it; give all "
            "three lists or none).", read_only=True) for _k in ("natural_frequency_hz", "damping_ratio", "gain")],
    *[Param(f"faults.baseline.{_k}_std", "double[]", [], f"Uncertainty of the given baseline {_k} per mode "
            "(empty: exact).", 0.0, None, True) for _k in ("natural_frequency_hz", "damping_ratio", "gain")],
    Param("faults.min_change.natural_frequency", "double", 0.02, "Minimum relevant relative change of a natural "
          "frequency for a fault.", 1e-6, 10.0),
    Param("faults.min_change.damping", "double", 0.20, "Minimum relevant relative change of a damping ratio for "
          "a fault.", 1e-6, 10.0),
    Param("faults.min_change.gain", "double", 0.10, "Minimum relevant relative change of a modal gain for a "
          "fault.", 1e-6, 10.0),
    Param("faults.min_change.spread_factor", "double", 3.0, "A change is relevant only if it also exceeds this many "
          "times the healthy fluctuation (spread) of the estimate seen while the baseline was learned; 0 disables.",
          0.0, 100.0),
    Param("faults.cusum.reference_sigma", "double", 0.5, "CUSUM reference value k: deviations below k standard "
          "deviations do not accumulate evidence.", 0.0, 100.0),
    Param("faults.cusum.false_alarm_interval_days", "double", 100.0, "Mean time between false alarms of one "
          "CUSUM side (per mode and quantity) on healthy data, before the relevance and persistence checks; sets "
          "the CUSUM threshold (Siegmund's approximation).", 1e-6, 1e9),
    Param("faults.cusum.threshold", "double", 0.0, "Fixed CUSUM threshold h in independent estimates (one per two "
          "memory lengths); 0: derived from faults.cusum.false_alarm_interval_days.", 0.0, 1e4),
    Param("faults.persistence_s", "double", 0.0, "A suspected fault must persist this long (s) to be confirmed; "
          "the larger of this and faults.persistence_memory_lengths x the mode's memory is used.", 0.0, 1e6),
    Param("faults.persistence_memory_lengths", "double", 1.0, "Persistence before confirming, in memory "
          "lengths of the mode.", 0.0, 1000.0),
    Param("faults.fast.memory_fraction", "double", 1.0, "Fast tracking (opt-in): once a mode's change detector (its "
          "CUSUM) fires, the mode's memory is shortened to this fraction (never below 3 decay times of the mode) for "
          "faults.fast.memory_lengths memory lengths, so the estimate reaches a changed plant's value and the alarm "
          "comes sooner; 1 (default) turns it off. Measured: faster alarms on well-separated modes, but a wrong-mode "
          "event on a close pair (docs/benchmarks.md).", 0.01, 1.0),
    Param("faults.fast.memory_lengths", "double", 1.5, "How long a shortened memory lasts, in (configured) memory "
          "lengths of the mode.", 0.0, 1000.0),
    Param("faults.clear_s", "double", 0.0, "A fault clears after its deviation stayed away this long (s); the "
          "larger of this and faults.clear_memory_lengths x the mode's memory is used.", 0.0, 1e6),
    Param("faults.clear_memory_lengths", "double", 2.0, "Hysteresis before clearing, in memory lengths of the "
          "mode.", 0.0, 1000.0),
    Param("faults.clear_fraction", "double", 0.5, "A fault counts as gone when its deviation is below this "
          "fraction of the minimum relevant change.", 0.01, 0.99),
    Param("faults.health.holdoff_memory_lengths", "double", 2.0, "Structural alarms stay held back this many "
          "(longest) memory lengths after an estimator-health or data problem ended.", 0.0, 1000.0),
    Param("faults.health.holdoff_min_s", "double", 0.5, "Minimum hold-off after a health problem (s).", 0.0, 1e6),
    Param("faults.health.max_condition", "double", 1e12, "Loss of excitation when the estimator's IV condition "
          "number exceeds this.", 1.0, 1e300),
    Param("faults.health.max_projection_fraction", "double", 0.01, "Projection storm when more than this "
          "fraction of updates needed the stability projection ([RA-SRIVC] §4.7).", 0.0, 1.0),
    Param("faults.health.residual_jump_ratio", "double", 3.0, "Residual-variance jump when the residual "
          "variance exceeds its healthy level by this factor (advisory: a fault is then confirmed only if it "
          "began together with the jump).", 1.0, 1e12),
    Param("faults.health.max_relative_std", "double", 0.25, "Loss of excitation when a mode's frequency or "
          "gain std exceeds this fraction of its value.", 1e-6, 1e6),
    Param("faults.health.max_parameter_ratio", "double", 10.0, "Divergence when a frequency or gain moves by "
          "more than this factor from its initial estimate.", 1.01, 1e6),
    Param("faults.health.stuck_s", "double", 0.25, "Stuck sensor when the output repeats the exact same value "
          "for this long (s).", 0.0, 1e6),
    Param("faults.health.stuck_min_samples", "int", 10, "... and for at least this many samples.", 2, 100000000),
    Param("faults.health.gap_tolerance", "double", 0.5, "A data gap is a sample spacing above (1 + this) / "
          "loop_rate_hz; the estimator is re-primed after it.", 0.01, 1000.0),
    Param("faults.health.repeated_output_is_missing", "bool", True, "An output exactly equal to the previous one "
          "is a dropped sample held by the receiver: skip it (set false for coarsely quantized sensors)."),
    Param("faults.health.max_repeated_fraction", "double", 0.01, "Health warning when more than this fraction of "
          "the outputs between two reports repeat their previous value.", 0.0, 1.0),
]

CORE_ROWS: dict[str, Param] = {p.name: p for p in (*ESTIMATOR_PARAMS, *FAULT_PARAMS)}


def core_param(name: str) -> Param:
    """The row ``name`` of :data:`ESTIMATOR_PARAMS` or :data:`FAULT_PARAMS`."""
    try:
        return CORE_ROWS[name]
    except KeyError:
        raise KeyError(f"no core parameter '{name}' (core/params.py)") from None


def _typed(p: Param, value: Any) -> Any:
    """``value`` as the field type of ``p``: float, int, bool, str, or a tuple of them for a list type."""
    cast = {"bool": bool, "int": int, "double": float, "string": str}[p.type.removesuffix("[]")]
    return tuple(cast(v) for v in value) if p.type.endswith("[]") else cast(value)


def from_param(*names: str) -> Any:
    """A dataclass field filled from the row ``names[0]`` (or a tuple field, one entry per row of ``names``); its
    default is the row's default."""
    rows = [core_param(n) for n in names]
    defaults = [_typed(p, p.default) for p in rows]
    return field(default=defaults[0] if len(rows) == 1 else tuple(defaults), metadata={"params": names})


def field_params(f: Field[Any]) -> tuple[str, ...]:
    """The parameter names a settings field is filled from (declared by :func:`from_param`)."""
    if "params" not in f.metadata:
        raise TypeError(f"settings field '{f.name}' names no parameter (declare it with from_param)")
    return tuple(f.metadata["params"])


S = TypeVar("S")


def settings_from_params(cls: type[S], params: Mapping[str, Any]) -> S:
    """Build the settings dataclass ``cls`` from flat ``{dotted name: value}`` parameters (validated by
    config.validate_params; a missing name takes its row's default)."""
    values: dict[str, Any] = {}
    for f in fields(cls):  # type: ignore[arg-type]
        names = field_params(f)
        vals = [_typed(core_param(n), params.get(n, core_param(n).default)) for n in names]
        values[f.name] = vals[0] if len(names) == 1 else tuple(vals)
    return cls(**values)


def settings_as_params(settings: Any) -> dict[str, Any]:
    """The flat parameters a settings dataclass was built from (lists for list types): the inverse of
    :func:`settings_from_params`."""
    out: dict[str, Any] = {}
    for f in fields(settings):
        names = field_params(f)
        value = getattr(settings, f.name)
        for name, v in zip(names, value if len(names) > 1 else (value,), strict=True):
            out[name] = list(v) if core_param(name).type.endswith("[]") else v
    return out


@dataclass(frozen=True)
class EstimatorOptions:
    """Options of the recursive estimator (``estimator.*``), read by ``RecursiveAdditiveSRIVC.from_config``."""

    block_sweeps: int = from_param("estimator.block_sweeps")
    refinements: int = from_param("estimator.refinements")
    stability_projection: bool = from_param("estimator.stability_projection")
    output_subsampling: int = from_param("estimator.output_subsampling")
    p0_relative_a: float = from_param("estimator.p0_relative_a")
    p0_relative_b: float = from_param("estimator.p0_relative_b")
    p0_policy: str = from_param("estimator.p0_policy")
    init_method: str = from_param("estimator.init_method")
    init_max_iterations: int = from_param("estimator.init_max_iterations")
    filter_smoothing: str = from_param("estimator.filter_smoothing")
    init_warmup_s: float = from_param("estimator.init_warmup_s")
    guess_spread: float = from_param("estimator.guess_spread")
    order_check_memory_lengths: float = from_param("estimator.order_check_memory_lengths")
    order_check_relevance: float = from_param("estimator.order_check_relevance")

    @classmethod
    def from_params(cls, params: Mapping[str, Any]) -> EstimatorOptions:
        """From flat parameters (missing names keep their defaults)."""
        return settings_from_params(cls, params)
