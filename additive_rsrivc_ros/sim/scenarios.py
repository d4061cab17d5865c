"""Named simulation scenarios with known truth ([RA-SRIVC] §5, §6; [A-SRIVC] §5.2, §6).

Each scenario is seeded and deterministic and has a params YAML ``config/<name>.yaml`` for the estimator
(the controller, loop rate and input delay are read from that file, so the simulated loop and the estimator
configuration cannot disagree). The plant may have more modes than the estimator's K (unmodelled modes); the
plant's modes are ordered so that the estimated ones come first.

    data = build("beam_fault", duration_s=30, seed=1, fault_time_s=15)
    data.truth            # (K_estimated, N, 3): f_hz, zeta, gain per sample for the configured modes
    data.write_bag(path)  # rosbag2 with /reference, /plant_input, /plant_output, /truth/modes, /truth/fault

Overrides (keyword arguments of :func:`build`) are listed per scenario in ``SCENARIOS[name].parameters``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from ..config import MonitorConfig, load_config
from ..core.vocabulary import quantity_of
from .plants import BEAM_MODES, BEAM_NOISE_STD, PAPER_MODES
from .simulate import (
    ModalChange,
    PlantMode,
    SensorFault,
    SimulationResult,
    arma_noise,
    multisine,
    simulate_modes,
    square_wave,
    sum_of_sines,
    time_vector,
    white_noise,
)


def config_dir() -> Path:
    """The params files: ``config/`` of a source tree (checkout, editable install, colcon --symlink-install), else
    the copy that setup.py's build step puts into the package (``additive_rsrivc_ros/data/config``: pip install,
    wheel, colcon build). ``share/additive_rsrivc_ros/config`` holds the same files for ``--params-file``."""
    root = Path(__file__).resolve().parents[2]
    if (root / "package.xml").is_file() and (root / "config").is_dir():
        return root / "config"
    return Path(str(resources.files("additive_rsrivc_ros") / "data" / "config"))


@dataclass
class ScenarioData:
    """A simulated scenario: samples, truth, fault schedule and the estimator's params file."""

    name: str
    seed: int
    t: np.ndarray
    r: np.ndarray | None
    u: np.ndarray
    y: np.ndarray
    x: np.ndarray
    truth: np.ndarray              # (K_estimated, N, 3) f_hz, zeta, gain of the configured modes
    truth_all: np.ndarray          # (K_plant, N, 3) every plant mode (estimated ones first)
    fault_events: list[dict]       # as published on /truth/fault (see bagio)
    changes: list[ModalChange]
    sensor_faults: list[SensorFault]
    config_path: Path
    config: MonitorConfig
    sim: SimulationResult
    parameters: dict[str, Any] = field(default_factory=dict)

    @property
    def rate_hz(self) -> float:
        return self.config.loop_rate_hz

    @property
    def n_estimated(self) -> int:
        return self.config.K

    def write_bag(self, path: str | Path, storage: str = "mcap", truth_rate_hz: float = 10.0) -> Path:
        """Write the scenario as a rosbag2 (bagio.write_bag) with its truth topics."""
        from ..io.bagio import write_bag

        custom = {"additive_rsrivc.scenario": self.name, "additive_rsrivc.seed": str(self.seed),
                  "additive_rsrivc.params_file": self.config_path.name,
                  "additive_rsrivc.estimated_modes": str(self.n_estimated),
                  "additive_rsrivc.parameters": _json(self.parameters)}
        return write_bag(path, self.rate_hz, self.u, self.y, self.r, truth_modal=self.truth_all,
                         truth_rate_hz=truth_rate_hz, fault_events=self.fault_events, storage=storage,
                         custom_data=custom)


def _json(obj: Any) -> str:
    import json

    return json.dumps(obj, sort_keys=True, default=float)


# ----------------------------------------------------------------------------------------------------------------
# Fault truth encoding
# ----------------------------------------------------------------------------------------------------------------
def _change_desc(c: ModalChange) -> dict:
    return {"kind": "structural", "mode": c.mode + 1, "quantity": quantity_of(c.quantity),
            "direction": "down" if c.relative_change < 0 else "up", "relative_change": c.relative_change,
            "shape": c.shape, "start_s": c.start_s,
            "end_s": c.start_s + (0.0 if c.shape == "step" else c.duration_s)}


def _sensor_desc(f: SensorFault) -> dict:
    d = {"kind": "sensor", "type": f.kind, "start_s": f.start_s,
         "end_s": None if math.isinf(f.duration_s) else f.start_s + f.duration_s}
    if f.kind in ("bias", "drift", "stuck"):
        d["value"] = f.value
    if f.kind in ("drop", "nan"):
        d["fraction"] = f.fraction
    return d


def fault_events(changes: list[ModalChange], sensor_faults: list[SensorFault], duration_s: float) -> list[dict]:
    """The ``/truth/fault`` messages: a ``start`` message, then one per onset / ramp completion / end.

    Mode numbers are 1-based (as in the diagnostics); quantities use the events.csv vocabulary.
    """
    timeline: list[tuple[float, int, str, dict]] = []
    for i, c in enumerate(changes):
        d = _change_desc(c)
        timeline.append((c.start_s, i, "onset", d))
        if c.shape in ("ramp", "raised_cosine"):
            timeline.append((d["end_s"], i, "complete", d))
        elif c.shape == "bump":
            timeline.append((d["end_s"], i, "end", d))
    for j, f in enumerate(sensor_faults):
        d = _sensor_desc(f)
        timeline.append((f.start_s, len(changes) + j, "onset", d))
        if d["end_s"] is not None:
            timeline.append((d["end_s"], len(changes) + j, "end", d))
    timeline.sort(key=lambda e: (e[0], e[1]))
    active: dict[int, dict] = {}
    out = [{"time_s": 0.0, "event": "start", "active": []}]
    for time_s, key, event, desc in timeline:
        if time_s >= duration_s:
            continue
        if event == "end":
            active.pop(key, None)
        else:
            active[key] = desc
        out.append({"time_s": float(time_s), "event": event, "fault": desc,
                    "active": [active[k] for k in sorted(active)]})
    if len(out) > 1 and out[1]["time_s"] == 0.0:
        out[0]["active"] = []
    return out


# ----------------------------------------------------------------------------------------------------------------
# Scenario builders
# ----------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Scenario:
    name: str
    description: str
    default_duration_s: float
    parameters: dict[str, Any]
    builder: Callable[..., tuple]


def _finish(name: str, seed: int, cfg_path: Path, cfg: MonitorConfig, modes, sim: SimulationResult,
            changes: list[ModalChange], sensor: list[SensorFault], params: dict) -> ScenarioData:
    k = cfg.K
    if k > len(modes):
        raise ValueError(f"{cfg_path.name} configures {k} modes, the plant has {len(modes)}")
    duration = sim.t.size / cfg.loop_rate_hz
    return ScenarioData(
        name=name, seed=seed, t=sim.t, r=sim.r, u=sim.u, y=sim.y, x=sim.x, truth=sim.modal[:k],
        truth_all=sim.modal, fault_events=fault_events(changes, sensor, duration), changes=list(changes),
        sensor_faults=list(sensor), config_path=cfg_path, config=cfg, sim=sim, parameters=params)


def _paper_example(name, cfg_path, cfg, duration_s, rng, p):
    """[RA-SRIVC] §5 with raised-cosine ramps: omega1 -20 %, zeta2 -50 % over [100, 300] s; omega3 -15 %, zeta3 -30 %
    over [500, 800] s; r = 3 sin(0.005t) + sin 2t + sin 5t + sin 17.5t; white noise var 0.01."""
    t = time_vector(cfg.loop_rate_hz, duration_s)
    r = sum_of_sines(t, [3.0, 1.0, 1.0, 1.0], [0.005, 2.0, 5.0, 17.5])
    a0, a1 = p["drift1_start_s"], p["drift1_end_s"]
    b0, b1 = p["drift2_start_s"], p["drift2_end_s"]
    changes = [ModalChange(0, "frequency", -0.20, a0, a1 - a0, "raised_cosine"),
               ModalChange(1, "damping", -0.50, a0, a1 - a0, "raised_cosine"),
               ModalChange(2, "frequency", -0.15, b0, b1 - b0, "raised_cosine"),
               ModalChange(2, "damping", -0.30, b0, b1 - b0, "raised_cosine")]
    v = white_noise(t.size, p["noise_std"], rng)
    return PAPER_MODES, r, None, v, changes, []


def _beam_common(cfg, duration_s, rng, p):
    t = time_vector(cfg.loop_rate_hz, duration_s)
    r = square_wave(t, p["setpoint_hz"], p["setpoint_amplitude"])
    if p["dither_std"] > 0:
        r = r + white_noise(t.size, p["dither_std"], rng)
    v = white_noise(t.size, p["noise_std"], rng)
    return t, r, v


def _beam(name, cfg_path, cfg, duration_s, rng, p):
    """[RA-SRIVC] §6 / [A-SRIVC] §6 flexible beam: mode 2's stiffness manipulated smoothly (frequency down and back)."""
    t, r, v = _beam_common(cfg, duration_s, rng, p)
    a, b = p["manipulation_start_s"], p["manipulation_end_s"]
    changes = [ModalChange(1, "frequency", p["manipulation_depth"], a, b - a, "bump")] if b > a else []
    return BEAM_MODES, r, None, v, changes, []


def _beam_fault(name, cfg_path, cfg, duration_s, rng, p):
    """Healthy beam, then mode 2's natural frequency drops by ``fault_size`` at ``fault_time_s`` (step, or a
    raised-cosine ramp of ``fault_ramp_s``)."""
    t, r, v = _beam_common(cfg, duration_s, rng, p)
    ramp = p["fault_ramp_s"]
    fault_time = p["fault_time_s"] if p["fault_time_s"] is not None else duration_s / 2.0
    p["fault_time_s"] = fault_time
    changes = [ModalChange(p["fault_mode"] - 1, "frequency", -p["fault_size"], fault_time, ramp,
                           "raised_cosine" if ramp > 0 else "step")]
    return BEAM_MODES, r, None, v, changes, []


def _beam_healthy(name, cfg_path, cfg, duration_s, rng, p):
    """Long healthy beam run (false-alarm counting): constant parameters, the same noise."""
    t, r, v = _beam_common(cfg, duration_s, rng, p)
    return BEAM_MODES, r, None, v, [], []


def _open_loop_multisine(name, cfg_path, cfg, duration_s, rng, p):
    """Open loop, random-phase multisine input (log-spaced lines on the 1/period grid), coloured noise."""
    t = time_vector(cfg.loop_rate_hz, duration_s)
    period = p["multisine_period_s"]
    lines = np.unique(np.rint(np.geomspace(p["f_min_hz"], p["f_max_hz"], p["n_lines"]) * period)) / period
    u = multisine(t, lines[lines > 0], p["input_rms"], rng)
    v = arma_noise(t.size, p["noise_std"], rng, c=[1.0, 0.5], d=[1.0, -0.7])
    modes = (PlantMode(5.0, 0.05, 1.0), PlantMode(20.0, 0.02, 0.2), PlantMode(60.0, 0.01, 0.05))
    return modes, None, u, v, [], []


def _rigid_body(name, cfg_path, cfg, duration_s, rng, p):
    """Double integrator ``b0/p^2`` plus two flexible modes ([A-SRIVC] Remark 6, [RA-SRIVC] §4.6), PD control."""
    t = time_vector(cfg.loop_rate_hz, duration_s)
    r = square_wave(t, p["setpoint_hz"], p["setpoint_amplitude"])
    v = white_noise(t.size, p["noise_std"], rng)
    modes = (PlantMode(0.0, 0.0, 1.0, integrators=2), PlantMode(8.0, 0.02, 0.004), PlantMode(25.0, 0.01, 8e-4))
    changes = []
    if p["fault_time_s"] is not None:
        changes = [ModalChange(1, "frequency", -p["fault_size"], p["fault_time_s"])]
    return modes, r, None, v, changes, []


def _sensor_fault(name, cfg_path, cfg, duration_s, rng, p):
    """Healthy [RA-SRIVC] §5 plant, faulty sensor: bias step, stuck value, NaN samples and dropped samples."""
    t = time_vector(cfg.loop_rate_hz, duration_s)
    r = sum_of_sines(t, [3.0, 1.0, 1.0, 1.0], [0.005, 2.0, 5.0, 17.5])
    v = white_noise(t.size, p["noise_std"], rng)
    s = p["fault_time_s"]
    sensor = [SensorFault("bias", s, math.inf, p["bias"]),
              SensorFault("stuck", s + 100.0, 5.0, None),
              SensorFault("nan", s + 200.0, 50.0, fraction=p["nan_fraction"]),
              SensorFault("drop", s + 300.0, 50.0, fraction=p["drop_fraction"])]
    return PAPER_MODES, r, None, v, [], sensor


_BEAM_SIGNAL = {"setpoint_hz": 2.0, "setpoint_amplitude": 0.1, "dither_std": 0.0, "noise_std": BEAM_NOISE_STD}

SCENARIOS: dict[str, Scenario] = {s.name: s for s in (
    Scenario("paper_example", "[RA-SRIVC] §5: 3 modes at 20 Hz, closed loop, drifting omega1/zeta2 and omega3/zeta3",
             1000.0, {"noise_std": 0.1, "drift1_start_s": 100.0, "drift1_end_s": 300.0, "drift2_start_s": 500.0,
                      "drift2_end_s": 800.0}, _paper_example),
    Scenario("beam", "[RA-SRIVC] §6 flexible beam at 4096 Hz: 4 plant modes (K = 2 estimated), mode-2 frequency "
             "down 10 % and back over [40, 100] s", 120.0,
             {**_BEAM_SIGNAL, "manipulation_start_s": 40.0, "manipulation_end_s": 100.0,
              "manipulation_depth": -0.10}, _beam),
    Scenario("beam_fault", "healthy beam, then a 5 % step drop of mode 2's frequency at fault_time_s "
             "(default: the middle)", 60.0,
             {**_BEAM_SIGNAL, "fault_time_s": None, "fault_size": 0.05, "fault_ramp_s": 0.0, "fault_mode": 2},
             _beam_fault),
    Scenario("beam_healthy", "long healthy beam run for false-alarm counting", 300.0, dict(_BEAM_SIGNAL),
             _beam_healthy),
    Scenario("open_loop_multisine", "open loop, 3 modes at 1 kHz, multisine input, coloured (ARMA) noise", 120.0,
             {"input_rms": 1.0, "f_min_hz": 0.5, "f_max_hz": 150.0, "n_lines": 60, "multisine_period_s": 20.0,
              "noise_std": 0.01}, _open_loop_multisine),
    Scenario("rigid_body", "double integrator + 8 Hz and 25 Hz modes at 1 kHz, PD control", 120.0,
             {"setpoint_hz": 0.5, "setpoint_amplitude": 0.1, "noise_std": 2e-5, "fault_time_s": None,
              "fault_size": 0.05}, _rigid_body),
    Scenario("sensor_fault", "healthy [RA-SRIVC] §5 plant, faulty sensor: bias from fault_time_s, stuck +100 s, NaN "
             "samples +200 s, dropped samples +300 s", 600.0,
             {"noise_std": 0.1, "fault_time_s": 150.0, "bias": 0.5, "nan_fraction": 0.02, "drop_fraction": 0.05},
             _sensor_fault),
)}


def list_scenarios() -> list[str]:
    return sorted(SCENARIOS)


def build(name: str, duration_s: float | None = None, seed: int = 0, **overrides: Any) -> ScenarioData:
    """Simulate scenario ``name`` (seeded, deterministic). Unknown names or overrides raise ValueError."""
    if name not in SCENARIOS:
        raise ValueError(f"unknown scenario {name!r} (known: {', '.join(list_scenarios())})")
    sc = SCENARIOS[name]
    unknown = sorted(set(overrides) - set(sc.parameters))
    if unknown:
        raise ValueError(f"scenario {name!r} has no parameter(s) {', '.join(unknown)} "
                         f"(known: {', '.join(sorted(sc.parameters))})")
    duration = sc.default_duration_s if duration_s is None else float(duration_s)
    if not (math.isfinite(duration) and duration > 0):
        raise ValueError(f"duration must be > 0 s, got {duration_s}")
    if not isinstance(seed, int | np.integer) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    params = {**sc.parameters, **overrides}
    cfg_path = config_dir() / f"{name}.yaml"
    cfg = load_config(cfg_path)
    rng = np.random.default_rng([int(seed), sum(map(ord, name))])
    modes, r, u, v, changes, sensor = sc.builder(name, cfg_path, cfg, duration, rng, params)
    sim = simulate_modes(modes, cfg.loop_rate_hz, changes=changes, r=r, u=u,
                         controller=cfg.controller if cfg.closed_loop else None,
                         input_delay=cfg.input_delay_samples, noise=v, sensor_faults=sensor, rng=rng)
    return _finish(name, int(seed), cfg_path, cfg, modes, sim, changes, sensor, params)
