"""Parameters of the monitor: one declarative table shared by the ROS node and the offline tools.

The same params YAML (``additive_rsrivc_monitor: ros__parameters: ...``, docs/INTERFACE.md) drives
``rsrivc_monitor``, ``rsrivc_diagnose`` and ``rsrivc_identify``. Every parameter is declared once, as a
:class:`Param` row (name, type, default, description, range, choices, read-only): the node declares each with a
descriptor built from it; :func:`load_params_file` and :func:`validate_params` apply the same types, ranges and
cross-checks offline; :meth:`MonitorConfig.from_params` builds the typed view; config/template.yaml and the README's
parameter table are rendered from the rows (scripts/generate_param_docs.py; test_config checks they are current).

Sections (:data:`SECTIONS`, in declaration order): ``CORE_PARAMS`` (plant, modes, and the ``estimator.*`` rows),
``SIGNAL_PARAMS`` (topics), ``ALIGN_PARAMS`` (stream alignment), ``FAULT_PARAMS`` (diagnosis), ``NODE_PARAMS``
(node only). The ``estimator.*`` and ``faults.*`` rows live in core/params.py, next to the settings dataclasses
they fill (EstimatorOptions, core.faults.FaultSettings), because core/ must not import this module.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import yaml

from .core.controller import DiscreteController
from .core.model import SubmodelStructure, guess_structure, guess_theta
from .core.params import DEFAULT_MEMORY_S, ESTIMATOR_PARAMS, FAULT_PARAMS, EstimatorOptions, Param

if TYPE_CHECKING:   # annotations only: imported where used (the fault monitor and aligner are heavier)
    from .core.diagnosis.faults import FaultSettings
    from .core.input.alignment import AlignmentSettings

DEFAULT_NODE_NAME = "additive_rsrivc_monitor"


def params_key(node_name: str = DEFAULT_NODE_NAME) -> str:
    """The top-level key a written params file gives the node: ``/**/<name>`` for a plain name (rcl applies it to a
    node of that name in any namespace, the root one included), a name with a namespace as given (absolute)."""
    name = node_name.strip().strip("/")
    return f"/{name}" if "/" in name else f"/**/{name}"


class ParamError(ValueError):
    """A parameter file or value that cannot be used; the message names the parameter."""


CORE_PARAMS: list[Param] = [
    Param("loop_rate_hz", "double", 0.0, "Sample rate of r, u, y in Hz (required).", 0.1, 1e6, True),
    Param("closed_loop", "bool", True, "Closed-loop instrument z = S_uo(q) r ([RA-SRIVC] eq. 33); false: z = u.",
          read_only=True),
    Param("controller.numerator", "double[]", [], "Discrete controller C_d numerator, ascending powers of q^-1.",
          read_only=True),
    Param("controller.denominator", "double[]", [1.0], "Discrete controller C_d denominator, ascending q^-1.",
          read_only=True),
    Param("input_delay_samples", "int", 0, "Known input delay in samples.", 0, 10000, True),
    Param("modes.natural_frequency_hz", "double[]", [], "Initial guess of each mode's natural frequency (Hz); "
          "its length defines K. 0 for a pure rigid-body mode b0/p^l. Empty (with empty damping_ratio and gain): "
          "the modes are found from the data (core/identification/modefind.py; modes.count).", 0.0, None, True),
    Param("modes.damping_ratio", "double[]", [], "Initial guess of each mode's damping ratio.", 0.0, 10.0, True),
    Param("modes.gain", "double[]", [], "Initial guess of each mode's DC gain b0.", None, None, True),
    Param("modes.integrators", "int[]", [], "Poles at the origin per mode (rigid body: 2); default 0. Ignored "
          "when the modes are found from the data (a rigid body is detected there).", 0, 2, True),
    Param("modes.memory_s", "double[]", [], "Forgetting memory per mode in s: "
          "lambda = 1 - 1/(memory_s * loop_rate_hz). One value applies to every mode; empty: "
          f"{DEFAULT_MEMORY_S:g} s.", 1e-3, 1e7),
    Param("modes.count", "int", 0, "Number of modes to find from the data when no guesses are given (a detected "
          "rigid body counts as one); 0: choose it by held-out output error (at most modes.max_count). With "
          "guesses it must be 0 or their number.", 0, 32, True),
    Param("modes.max_count", "int", 6, "Largest number of modes tried when modes.count is 0.", 1, 32, True),
    Param("modes.frequency_range_hz", "double[]", [], "Search band [low, high] (Hz) for finding modes from the "
          "data; empty: the whole band the data excite.", 0.0, None, True),
    Param("init_duration_s", "double", 5.0, "Data used for the offline initialization before the recursion "
          "starts ([RA-SRIVC] Algorithm 2 step 1).", 0.0, 1e5, True),
    Param("publish_rate_hz", "double", 10.0, "Rate of the estimates on ~/modes (reports, in the data's time; "
          "/diagnostics: diagnostics_period_s). At most 100 Hz: a report costs the pipeline ~1.3 ms (measured), so "
          "1000 Hz would need more than a core and stop the consumption of 4096 Hz inputs "
          "(scripts/bench_node.py --publish-rate).", 0.01, 100.0),
    *ESTIMATOR_PARAMS,
]

# Defaults shared by the rows of the three signals and SignalConfig.
SIGNAL_DEFAULTS: dict[str, str] = {"type": "std_msgs/msg/Float64", "joint": "", "field": "position"}
SIGNAL_PARAMS: list[Param] = []
for _sig, _topic in (("reference", "reference"), ("input", "plant_input"), ("output", "plant_output")):
    SIGNAL_PARAMS += [
        Param(f"{_sig}.topic", "string", _topic, f"Topic of the {_sig} signal. A relative name resolves in the "
              f"node's namespace (/{_topic} in the root namespace, /<ns>/{_topic} under -r __ns:=/<ns>); remap it "
              f"(-r {_topic}:=/other) rather than changing it. In a bag, a relative name matches /{_topic}.",
              read_only=True),
        Param(f"{_sig}.type", "string", SIGNAL_DEFAULTS["type"], f"Message type of the {_sig} signal.",
              read_only=True, choices=("std_msgs/msg/Float64", "sensor_msgs/msg/JointState")),
        Param(f"{_sig}.joint", "string", SIGNAL_DEFAULTS["joint"], f"JointState joint name of the {_sig} signal "
              "(empty: first joint).", read_only=True),
        Param(f"{_sig}.field", "string", SIGNAL_DEFAULTS["field"], f"JointState field of the {_sig} signal.",
              read_only=True, choices=("position", "velocity", "effort")),
    ]

SIGNAL_PARAMS += [
    Param("block.topic", "string", "", "Block input instead of the three per-sample topics: topic of "
          "std_msgs/msg/Float64MultiArray blocks, dim[0] 'sample' (N rows), dim[1] 'signal' (4), row-major columns "
          "index, reference, input, output (index = the controller's sample counter; open loop: reference ignored). "
          "Relative names resolve in the node's namespace. Empty: off (reference/input/output topics are used).",
          read_only=True),
    Param("block.reorder_s", "double", 0.05, "Block input: rows after a missing index wait this long (arrival "
          "time) for a late block that fills the hole before the hole is a data gap.", 0.0, 10.0, True),
    Param("block.batch_s", "double", 0.05, "Block input: the estimation worker feeds the estimator at most this "
          "often, all blocks that arrived since in one call (each call has a fixed cost; scripts/bench_node.py); adds "
          "up to this much delay. 0: every block at once.", 0.0, 1.0, True),
]

# Verified stream alignment (core/input/alignment.py): the controller invariant u = C_d(q)(r - y) re-pairs r, u, y.
ALIGN_PARAMS: list[Param] = [
    Param("alignment.mode", "string", "auto", "Verify and re-establish the pairing of r, u, y from the controller "
          "invariant u = C_d(q)(r - y): auto (closed loop with Float64 signals; JointState stamps are exact) or off.",
          read_only=True, choices=("auto", "off")),
    Param("alignment.max_shift", "int", 3, "Largest index offset of u or r against y searched (samples).", 1, 20,
          True),
    Param("alignment.lag_s", "double", 0.008, "Samples are released this late so that a shift detected within it "
          "is corrected before the estimator sees it (s; at least a few samples).", 0.0, 10.0, True),
    Param("alignment.switch_nats", "double", 40.0, "Evidence (log-likelihood ratio, nats) a different offset needs "
          "over the current one before the streams are re-aligned.", 5.0, 1e6, True),
]

# Node-only parameters (autostart, state_file, ...): owned by node.py.
NODE_PARAMS: list[Param] = [
    Param("autostart", "bool", True, "Configure and activate the lifecycle node on start.", read_only=True),
    Param("state_file", "string", "", "JSON file the estimator, baseline and fault state are saved to on shutdown "
          "(and by ~/save_state) and restored from on start; empty: no persistence.", read_only=True),
    Param("stale_timeout_s", "double", 1.0, "A signal topic without a message for this long is silent: /diagnostics "
          "goes STALE.", 0.01, 3600.0),
    Param("qos_depth", "int", 0, "Keep-last depth of the reliable signal subscriptions; 0: five seconds of samples "
          "(at least 100), enough to ride out a stalled executor without losing data.", 0, 10000000, True),
    Param("qos_reliable", "bool", True, "Subscribe RELIABLE (no loss; does not match BEST_EFFORT publishers) or "
          "BEST_EFFORT (matches any publisher, may lose samples under load).", read_only=True),
    Param("diagnostics_period_s", "double", 1.0, "Period of the /diagnostics array (s); 1 s is the "
          "diagnostic_updater norm. ~/modes goes out at publish_rate_hz, independently.", 0.05, 60.0),
    Param("hardware_id", "string", "", "hardware_id of the /diagnostics statuses (e.g. the axis or drive serial "
          "number, what rqt_robot_monitor groups devices by); empty: the node's full name.", read_only=True),
    Param("block_period_s", "double", 0.002, "Period of the estimation worker: queued samples are aligned and "
          "fed to the estimator in blocks at this period.", 1e-4, 1.0, True),
    Param("sync.max_backlog_s", "double", 0.25, "Float64 topics: one topic ahead of another by more than this much "
          "data for longer than sync.stall_s is a count mismatch (resynchronize).", 1e-3, 100.0),
    Param("sync.stall_s", "double", 4.0, "Float64 topics: how long one topic may lag the others (silent or "
          "behind) before it is a count mismatch or a lost topic: reliable DDS recovers a lost datagram only at the "
          "writer's next heartbeat (Fast DDS: every 3 s), and that topic stalls meanwhile. Pending samples wait; "
          "nothing is lost.", 0.0, 100.0, True),
    Param("sync.gap_s", "double", 0.0, "Float64 topics: a jump of the samples' lateness by more than this that a "
          "catch-up burst does not take back is an input pause (time gap, filters re-primed); 0: max(0.1 s, 10 "
          "samples).", 0.0, 100.0),
    Param("sync.hold_s", "double", 0.2, "Float64 topics: wait this long for a catch-up burst before a late "
          "sample is declared a pause (only delays estimation while such a decision is pending).", 0.0, 10.0),
    Param("sync.quiet_s", "double", 0.5, "Float64 topics: when every topic has been quiet this long, unequal "
          "message counts are a count mismatch (the unmatched messages are discarded); must exceed the largest "
          "delay between the publications of one sample's r, u and y.", 0.01, 100.0),
    Param("sync.max_queue_s", "double", 10.0, "Bound of every input topic's queue in seconds of samples (at "
          "loop_rate_hz, at least qos_depth samples; a fixed number of bytes per sample): beyond it the oldest "
          "samples are dropped, counted per topic and reported once per episode. Must exceed "
          "sync.stall_s and sync.max_backlog_s.", 0.5, 600.0, True),
    Param("sync.rate_window_s", "double", 2.0, "Window over which each topic's arrival rate is measured and "
          "compared with loop_rate_hz (times the clock speed under use_sim_time).", 0.2, 60.0, True),
    Param("sync.rate_tolerance", "double", 0.02, "Relative difference between a topic's arrival rate and "
          "loop_rate_hz above which (in two consecutive checks) the estimator status warns of a wrong time base.",
          0.001, 1.0, True),
]


# The sections of the table, in declaration order, with the banner config/template.yaml shows above each.
SECTIONS: list[tuple[str, list[Param]]] = [
    ("Plant, controller, modes and estimator (edit these for your plant)", CORE_PARAMS),
    ("Input topics (std_msgs/msg/Float64: aligned by arrival order; sensor_msgs/msg/JointState: by header stamp)",
     SIGNAL_PARAMS),
    ("Verified alignment of r, u, y (closed loop): the controller invariant u = C_d(q)(r - y) must hold sample by "
     "sample; a lost or repeated message on one topic is found and corrected (or reported)", ALIGN_PARAMS),
    ("Fault diagnosis (defaults are sensible; thresholds are changeable at runtime)", FAULT_PARAMS),
    ("Node only", NODE_PARAMS),
]


def all_params() -> list[Param]:
    """Every parameter row, in declaration order."""
    return [p for _, rows in SECTIONS for p in rows]


def param_table() -> dict[str, Param]:
    return {p.name: p for p in all_params()}


def _flatten(d: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, Mapping):
            out.update(_flatten(v, key + "."))
        else:
            out[key] = v
    return out


def _coerce(p: Param, value: Any) -> Any:
    """Check and convert one value to the parameter's type (ints are accepted for doubles)."""
    def scalar(t: str, v: Any) -> Any:
        if t == "bool":
            if isinstance(v, bool):
                return v
        elif t == "int":
            if isinstance(v, int | np.integer) and not isinstance(v, bool):
                return int(v)
        elif t == "double":
            if isinstance(v, int | float | np.integer | np.floating) and not isinstance(v, bool):
                return float(v)
        elif t == "string":
            if isinstance(v, str):
                return v
        raise ParamError(f"parameter '{p.name}' must be of type {p.type}, got {v!r}")

    if p.type.endswith("[]"):
        if not isinstance(value, list | tuple | np.ndarray):
            raise ParamError(f"parameter '{p.name}' must be a list ({p.type}), got {value!r}")
        out = [scalar(p.type[:-2], v) for v in value]
    else:
        out = scalar(p.type, value)
    vals = out if isinstance(out, list) else [out]
    for v in vals:
        if isinstance(v, float) and not math.isfinite(v):
            raise ParamError(f"parameter '{p.name}' must be finite, got {v!r}")
        if isinstance(v, int | float) and not isinstance(v, bool):
            if p.min is not None and v < p.min:
                raise ParamError(f"parameter '{p.name}' = {v!r} is below its minimum {p.min}")
            if p.max is not None and v > p.max:
                raise ParamError(f"parameter '{p.name}' = {v!r} is above its maximum {p.max}")
        if p.choices and isinstance(v, str) and v not in p.choices:
            raise ParamError(f"parameter '{p.name}' = {v!r} is not one of {', '.join(p.choices)}")
    return out


def validate_params(values: Mapping[str, Any], *, strict: bool = True) -> dict[str, Any]:
    """Apply defaults, types and ranges to a flat ``{dotted name: value}`` mapping.

    Unknown names raise :class:`ParamError` when ``strict`` (a misspelt parameter should not be silently
    ignored). Cross-parameter checks are done by :meth:`MonitorConfig.from_params`.
    """
    table = param_table()
    unknown = sorted(set(values) - set(table) - {"use_sim_time"})
    if unknown and strict:
        raise ParamError(f"unknown parameter(s): {', '.join(unknown)}")
    out = {name: (list(p.default) if isinstance(p.default, list) else p.default) for name, p in table.items()}
    for name, value in values.items():
        if name in table:
            out[name] = _coerce(table[name], value)
    return out


def load_params_file(path: str | Path, node_name: str = DEFAULT_NODE_NAME) -> dict[str, Any]:
    """Read a ROS 2 params YAML and return the flat validated parameters for ``node_name``.

    Accepts the node's name (with or without a leading ``/`` or namespace) or the ``/**`` wildcard as
    top-level key, each with a ``ros__parameters`` mapping; later keys override earlier ones.
    """
    path = Path(path)
    try:
        doc = yaml.safe_load(path.read_text())
    except FileNotFoundError:
        raise ParamError(f"params file not found: {path}") from None
    except yaml.YAMLError as exc:
        raise ParamError(f"params file {path} is not valid YAML: {str(exc).splitlines()[0]}") from None
    if not isinstance(doc, Mapping):
        raise ParamError(f"params file {path} must map node names to 'ros__parameters'")
    merged: dict[str, Any] = {}
    found = False
    for key, section in doc.items():
        name = str(key).strip("/")
        base = name.rsplit("/", 1)[-1]
        if name in ("**", "*") or base == node_name.strip("/").rsplit("/", 1)[-1]:
            if not isinstance(section, Mapping) or "ros__parameters" not in section:
                raise ParamError(f"params file {path}: section '{key}' has no 'ros__parameters'")
            merged.update(_flatten(section["ros__parameters"] or {}))
            found = True
    if not found:
        raise ParamError(f"params file {path} has no section for node '{node_name}' (or '/**')")
    return validate_params(merged)


@dataclass(frozen=True)
class ModeConfig:
    """Initial guess and forgetting memory of one mode."""

    natural_frequency_hz: float
    damping_ratio: float
    gain: float
    integrators: int = 0
    memory_s: float = DEFAULT_MEMORY_S

    @property
    def structure(self) -> SubmodelStructure:
        """Rigid body ``b0/p^l`` when the frequency is 0, otherwise a second-order mode."""
        return guess_structure(self.natural_frequency_hz, self.integrators)

    def theta0(self) -> np.ndarray:
        return guess_theta(self.natural_frequency_hz, self.damping_ratio, self.gain)


@dataclass(frozen=True)
class SignalConfig:
    """One input signal: the rows ``<signal>.topic/type/joint/field`` (defaults: SIGNAL_DEFAULTS)."""

    topic: str
    type: str = SIGNAL_DEFAULTS["type"]
    joint: str = SIGNAL_DEFAULTS["joint"]
    field: str = SIGNAL_DEFAULTS["field"]


@dataclass(frozen=True)
class MonitorConfig:
    """Typed view of the validated parameters (built by :meth:`from_params`)."""

    loop_rate_hz: float
    closed_loop: bool
    controller: DiscreteController | None
    input_delay_samples: int
    modes: tuple[ModeConfig, ...]
    init_duration_s: float
    publish_rate_hz: float
    estimator: EstimatorOptions
    signals: dict[str, SignalConfig]
    params: dict[str, Any] = field(repr=False)
    mode_count: int
    max_mode_count: int
    frequency_range_hz: tuple[float, float] | None = None

    @property
    def K(self) -> int:
        return len(self.modes)

    @property
    def structures(self) -> list[SubmodelStructure]:
        return [m.structure for m in self.modes]

    @property
    def alignment(self) -> AlignmentSettings:
        """The ``alignment.*`` parameters, typed."""
        from .core.input.alignment import AlignmentSettings

        p = self.params
        return AlignmentSettings(str(p.get("alignment.mode", "auto")), int(p.get("alignment.max_shift", 3)),
                                 float(p.get("alignment.lag_s", 0.008)), float(p.get("alignment.switch_nats", 40.0)))

    @property
    def mode_memories_s(self) -> tuple[float, ...]:
        """``modes.memory_s`` as given (one per mode, one for all, or none: the memories of found modes)."""
        return tuple(float(v) for v in self.params.get("modes.memory_s", []))

    @property
    def fault_settings(self) -> FaultSettings:
        """The ``faults.*`` parameters, typed (:class:`.core.faults.FaultSettings`)."""
        from .core.diagnosis.faults import FaultSettings

        return FaultSettings.from_params(self.params)

    @classmethod
    def from_params(cls, p: Mapping[str, Any]) -> MonitorConfig:
        """Cross-check validated parameters and build the typed configuration."""
        p = validate_params(p, strict=False) if set(param_table()) - set(p) else dict(p)
        rate = p["loop_rate_hz"]
        if not rate > 0.0:
            raise ParamError("parameter 'loop_rate_hz' is required and must be > 0")
        modes = _modes_from_params(p, rate)
        auto = _auto_mode_settings(p, len(modes))
        if sum(m.integrators > 0 for m in modes) > 1:
            raise ParamError("at most one mode may have integrators ([RA-SRIVC] §4.6)")
        controller = None
        if p["closed_loop"]:
            if not p["controller.numerator"]:
                raise ParamError("closed_loop is true but 'controller.numerator' is empty")
            try:
                controller = DiscreteController(tuple(p["controller.numerator"]), tuple(p["controller.denominator"]))
            except ValueError as exc:
                raise ParamError(f"controller: {exc}") from None
        est = EstimatorOptions.from_params(p)
        signals = {
            s: SignalConfig(**{f.name: p[f"{s}.{f.name}"] for f in fields(SignalConfig)})
            for s in ("reference", "input", "output")
        }
        return cls(
            loop_rate_hz=rate, closed_loop=p["closed_loop"], controller=controller,
            input_delay_samples=p["input_delay_samples"], modes=tuple(modes),
            init_duration_s=p["init_duration_s"], publish_rate_hz=p["publish_rate_hz"], estimator=est,
            signals=signals, params=dict(p), mode_count=auto[0], max_mode_count=auto[1],
            frequency_range_hz=auto[2],
        )

    @property
    def block_input(self) -> bool:
        """The node reads block messages (``block.topic`` set) instead of the three per-sample topics."""
        return bool(self.params.get("block.topic", ""))

    def with_block_input(self) -> MonitorConfig:
        """The node's view of a block-input configuration: one more signal ``block`` of type Float64MultiArray.

        Its rows are paired by the controller's index, so the pipeline's stream aligner (per-sample Float64 topics
        only, core/input/alignment.py) does not re-pair them. Offline tools keep the per-sample view: a bag of the three
        topics is still verified by the aligner."""
        sig = dict(self.signals)
        sig["block"] = SignalConfig(str(self.params["block.topic"]), "std_msgs/msg/Float64MultiArray")
        return replace(self, signals=sig)

    @property
    def auto_modes(self) -> bool:
        """No guesses: the modes are to be found from the data (core/identification/modefind.py)."""
        return self.K == 0

    def with_memory(self, memory_s: list[float]) -> MonitorConfig:
        """This configuration with ``modes.memory_s`` set (before the modes are known: the memories they get)."""
        return replace(self, params={**self.params, "modes.memory_s": list(memory_s)})

    def with_modes(self, modal: np.ndarray, integrators: list[int] | None = None) -> MonitorConfig:
        """This configuration with the modes ``modal`` (rows ``f_hz, zeta, gain``; frequency 0 = rigid body with
        ``integrators``) as guesses; ``modes.memory_s`` is kept if it lists one value per mode, else broadcast
        (one value) or 10 s."""
        modal = np.asarray(modal, dtype=float).reshape(-1, 3)
        k = modal.shape[0]
        ints = [int(v) for v in (integrators if integrators is not None else [0] * k)]
        mem = list(self.params["modes.memory_s"])
        mem = mem if len(mem) == k else [mem[0] if mem else DEFAULT_MEMORY_S] * k
        p = dict(self.params)
        p.update({"modes.natural_frequency_hz": [float(v) for v in modal[:, 0]],
                  "modes.damping_ratio": [float(v) for v in modal[:, 1]],
                  "modes.gain": [float(v) for v in modal[:, 2]], "modes.integrators": ints, "modes.memory_s": mem,
                  "modes.count": 0, "estimator.guess_spread": 0.0})   # modes from the data: no prior
        return MonitorConfig.from_params(p)


def _per_mode(p: Mapping[str, Any], name: str, k: int, default: Any) -> list[Any]:
    """A per-mode list: K entries, one entry for all modes, or empty for the default."""
    vals = list(p[name])
    if not vals:
        return [default] * k
    if len(vals) == 1 and k > 1:
        return vals * k
    if len(vals) != k:
        raise ParamError(f"parameter '{name}' has {len(vals)} entries, 'modes.natural_frequency_hz' has {k}")
    return vals


def _modes_from_params(p: Mapping[str, Any], rate: float) -> list[ModeConfig]:
    """The guessed modes (empty list: find them from the data)."""
    f = p["modes.natural_frequency_hz"]
    k = len(f)
    if k == 0:
        given = [n for n in ("modes.damping_ratio", "modes.gain") if p[n]]
        if given:
            raise ParamError(f"parameter '{given[0]}' is given but 'modes.natural_frequency_hz' is empty (give all "
                             "guesses, or none to find the modes from the data)")
        return []
    lists = {"modes.damping_ratio": p["modes.damping_ratio"], "modes.gain": p["modes.gain"]}
    for name, vals in lists.items():
        if len(vals) != k:
            raise ParamError(f"parameter '{name}' has {len(vals)} entries, 'modes.natural_frequency_hz' has {k}")
    ints = _per_mode(p, "modes.integrators", k, 0)
    mems = _per_mode(p, "modes.memory_s", k, DEFAULT_MEMORY_S)
    modes = []
    for i in range(k):
        fi, zi, gi = f[i], lists["modes.damping_ratio"][i], lists["modes.gain"][i]
        li, mi = ints[i], mems[i]
        if fi == 0.0 and li == 0:
            raise ParamError(f"mode {i + 1}: natural frequency 0 needs modes.integrators > 0 (rigid body)")
        if fi >= rate / 2.0:
            raise ParamError(f"mode {i + 1}: natural frequency {fi} Hz is not below Nyquist ({rate / 2} Hz)")
        if gi == 0.0:
            raise ParamError(f"mode {i + 1}: gain guess must be non-zero")
        if mi * rate < 2.0:
            raise ParamError(f"mode {i + 1}: memory_s {mi} s is shorter than two samples")
        modes.append(ModeConfig(fi, zi, gi, li, mi))
    return modes


def _auto_mode_settings(p: Mapping[str, Any], k: int) -> tuple[int, int, tuple[float, float] | None]:
    """``(modes.count, modes.max_count, modes.frequency_range_hz)`` checked against the guesses."""
    count, max_count = int(p["modes.count"]), int(p["modes.max_count"])
    if k and count not in (0, k):
        raise ParamError(f"parameter 'modes.count' = {count} but {k} mode guesses are given (use 0 or {k})")
    if count > max_count:
        raise ParamError(f"parameter 'modes.count' = {count} exceeds 'modes.max_count' = {max_count}")
    band = list(p["modes.frequency_range_hz"])
    if band and (len(band) != 2 or not band[0] < band[1]):
        raise ParamError(f"parameter 'modes.frequency_range_hz' must be [low, high] with low < high, got {band}")
    if band and band[0] >= p["loop_rate_hz"] / 2.0:
        raise ParamError("parameter 'modes.frequency_range_hz' starts above Nyquist")
    return count, max_count, (float(band[0]), float(band[1])) if band else None


def load_config(path: str | Path, node_name: str = DEFAULT_NODE_NAME) -> MonitorConfig:
    """:func:`load_params_file` followed by :meth:`MonitorConfig.from_params`."""
    return MonitorConfig.from_params(load_params_file(path, node_name))


def _yaml_scalar(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int | np.integer):
        return str(int(v))
    if isinstance(v, float | np.floating):
        text = repr(float(v))
        return text if ("." in text or "e" in text or "inf" in text or "nan" in text) else text + ".0"
    return '"' + str(v).replace("\\", "\\\\").replace('"', '\\"') + '"'


def _yaml_value(p: Param, v: Any) -> str:
    if p.type.endswith("[]"):
        cast = float if p.type == "double[]" else (lambda x: x)
        return "[" + ", ".join(_yaml_scalar(cast(x)) for x in v) + "]"
    return _yaml_scalar(float(v) if p.type == "double" else v)


def _comment_lines(text: str, indent: str, width: int = 112, *, break_on_hyphens: bool = True) -> list[str]:
    import textwrap

    return [f"{indent}# {line}" for line in textwrap.wrap(text, max(40, width - len(indent) - 2),
                                                          break_on_hyphens=break_on_hyphens)]


def _param_tree(rows: list[Param]) -> dict[str, Any]:
    """``{group: {subgroup: ..., leaf: Param}}`` of dotted names, in row order."""
    tree: dict[str, Any] = {}
    for p in rows:
        node = tree
        *parents, leaf = p.name.split(".")
        for key in parents:
            node = node.setdefault(key, {})
        node[leaf] = p
    return tree


def param_note(p: Param) -> str:
    """``[type; range; runtime]`` summary of a row, as config/template.yaml shows it after the description."""
    parts = [p.type]
    if p.min is not None and p.max is not None:
        parts.append(f"range [{p.min:g}, {p.max:g}]")
    elif p.min is not None:
        parts.append(f"min {p.min:g}")
    elif p.max is not None:
        parts.append(f"max {p.max:g}")
    if p.choices:
        parts.append("one of " + ", ".join(p.choices))
    parts.append("read-only (restart to change)" if p.read_only else "changeable at runtime")
    return "[" + "; ".join(parts) + "]"


@dataclass
class _YamlWriter:
    """Emits a parameter tree as commented params YAML (an empty list, which a ROS 2 params file cannot hold, is
    written commented out, with its ``examples`` value if there is one)."""

    values: Mapping[str, Any]
    annotate: bool = False                    # append param_note() to each description (template)
    examples: Mapping[str, Any] = field(default_factory=dict)
    group_notes: Mapping[str, str] = field(default_factory=dict)
    lines: list[str] = field(default_factory=list)

    def _has_value(self, node: dict[str, Any]) -> bool:
        return any(self._has_value(c) if isinstance(c, dict) else bool(self.values[c.name]) or
                   not c.type.endswith("[]") for c in node.values())

    def emit(self, node: dict[str, Any], depth: int, commented: bool = False, prefix: str = "") -> None:
        indent = "  " * depth
        for key, child in node.items():
            if isinstance(child, dict):
                off = commented or not self._has_value(child)
                if f"{prefix}{key}" in self.group_notes:
                    self.lines.extend(_comment_lines(self.group_notes[f"{prefix}{key}"], indent))
                self.lines.append(f"{indent}{'# ' if off else ''}{key}:")
                self.emit(child, depth + 1, off, f"{prefix}{key}.")
                continue
            v = self.values[child.name]
            text = f"{child.description} {param_note(child)}" if self.annotate else child.description
            self.lines.extend(_comment_lines(text, indent, break_on_hyphens=not self.annotate))
            off = commented or (child.type.endswith("[]") and not v)
            shown = self.examples.get(child.name, v) if off and not v else v
            self.lines.append(f"{indent}{'# ' if off else ''}{key}: {_yaml_value(child, shown)}")


def render_params_yaml(params: Mapping[str, Any], node_name: str = DEFAULT_NODE_NAME, header: str = "") -> str:
    """A complete, commented ROS 2 params YAML of ``params`` (every parameter of the table, in table order; an
    empty list, which a ROS 2 params file cannot hold, is written commented out). Reads back with
    :func:`load_params_file` to the same values."""
    table = param_table()
    writer = _YamlWriter(validate_params({k: v for k, v in params.items() if k in table}))
    writer.lines += [f"# {line}" if line else "#" for line in header.splitlines()]
    writer.lines += [f"{params_key(node_name)}:", "  ros__parameters:"]
    writer.emit(_param_tree(all_params()), 2)
    return "\n".join(writer.lines) + "\n"


# ------------------------------------------------------------------ generated documentation (the table is the source)
# scripts/generate_param_docs.py writes these; test_param_docs fails when the checked-in files drift from the table.
TEMPLATE_PATH = "config/template.yaml"
README_PATH = "README.md"
REGENERATE_COMMAND = "python scripts/generate_param_docs.py"

# The made-up plant config/template.yaml shows (2 modes at 12 and 85 Hz, 1 kHz loop, PI controller); every other
# parameter is shown at its default.
TEMPLATE_EXAMPLE: dict[str, Any] = {
    "loop_rate_hz": 1000.0, "controller.numerator": [0.5, -0.49], "controller.denominator": [1.0, -1.0],
    "input_delay_samples": 1, "modes.natural_frequency_hz": [12.0, 85.0], "modes.damping_ratio": [0.05, 0.02],
    "modes.gain": [1.0, 0.05], "modes.integrators": [0, 0], "modes.memory_s": [20.0, 10.0], "init_duration_s": 10.0,
}
# Values shown (commented out) for parameters whose value in the template is an empty list.
TEMPLATE_COMMENTED_EXAMPLE: dict[str, Any] = {"modes.frequency_range_hz": [1.0, 400.0]}
# Comment lines above a group of the template.
TEMPLATE_GROUP_NOTES: dict[str, str] = {
    "block": "Block input instead of the three topics above. Rows are paired by index (the sample time "
             "is index / loop_rate_hz): missing indices are data gaps, repeated ones are dropped, an index that goes "
             "back (controller restart) re-primes the estimator. Set stale_timeout_s above the time one block covers.",
    "faults.baseline": "A given baseline (every entry below is optional; uncomment to give a baseline):",
}
# The rows of the README's parameter table ("the main ones"); the others are in config/template.yaml.
README_PARAMS: tuple[str, ...] = (
    "loop_rate_hz", "closed_loop", "controller.numerator", "controller.denominator", "input_delay_samples",
    "modes.natural_frequency_hz", "modes.damping_ratio", "modes.gain", "modes.count", "modes.integrators",
    "modes.memory_s", "init_duration_s", "publish_rate_hz", "diagnostics_period_s",
)
README_BEGIN = f"<!-- BEGIN parameter table: generated from additive_rsrivc_ros/config.py by {REGENERATE_COMMAND} -->"
README_END = "<!-- END parameter table -->"
_BANNER = "=" * 100


def render_template(header: str) -> str:
    """config/template.yaml: ``header`` (its leading comment block, kept as written), then every parameter of the
    table by section, each with its description and :func:`param_note`, at :data:`TEMPLATE_EXAMPLE` or its
    default."""
    writer = _YamlWriter(validate_params(TEMPLATE_EXAMPLE), annotate=True, examples=TEMPLATE_COMMENTED_EXAMPLE,
                         group_notes=TEMPLATE_GROUP_NOTES)
    writer.lines += [*header.splitlines(), f"{params_key()}:", "  ros__parameters:"]
    for i, (title, rows) in enumerate(SECTIONS):
        if i:
            writer.lines.append("")
        writer.lines += ["    # " + _BANNER, *_comment_lines(title, "    "), "    # " + _BANNER]
        writer.emit(_param_tree(rows), 2)
    return "\n".join(writer.lines) + "\n"


def template_header(text: str) -> str:
    """The leading comment block of a template (the prose above the node's section, kept when regenerating)."""
    lines = text.splitlines()
    n = next((i for i, line in enumerate(lines) if line and not line.startswith("#")), len(lines))
    return "\n".join(lines[:n])


def render_readme_table() -> str:
    """The README's parameter table (:data:`README_PARAMS`) between its begin/end markers."""
    table = param_table()
    lines = [README_BEGIN, "", "| name | type | default | meaning |", "|---|---|---|---|"]
    for name in README_PARAMS:
        p = table[name]
        runtime = "" if p.read_only else " Changeable at runtime."
        text = (p.description + runtime).replace("|", "\\|")
        lines.append(f"| `{name}` | {p.type} | `{_yaml_value(p, p.default)}` | {text} |")
    others = sorted({p.name.split(".")[0] + (".*" if "." in p.name else "") for p in all_params()}
                    - {n.split(".")[0] + (".*" if "." in n else "") for n in README_PARAMS})
    lines.append(f"| {', '.join(f'`{g}`' for g in others)} | | | the other "
                 f"{len(table) - len(README_PARAMS)} parameters: see `{TEMPLATE_PATH}` |")
    return "\n".join([*lines, "", README_END])


def readme_with_table(readme: str) -> str:
    """``readme`` with the text between its parameter-table markers replaced by :func:`render_readme_table`."""
    begin, end = readme.find(README_BEGIN), readme.find(README_END)
    if begin < 0 or end < begin:
        raise ParamError(f"README has no '{README_BEGIN}' ... '{README_END}' markers")
    return readme[:begin] + render_readme_table() + readme[end + len(README_END):]
