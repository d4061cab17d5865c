"""Simulated recordings of machines over time, for ``rsrivc_fleet``'s tests, benchmarks and documentation figure.

The default machine (:data:`DEFAULT_MACHINE`): an open-loop plant at 1 kHz with two modes (5 Hz, zeta 0.05,
gain 1; 20 Hz, zeta 0.02, gain 0.2), driven by a random-phase multisine (0.5-150 Hz, rms 1) with white output
noise (std 0.01). Recording ``i`` starts ``interval_s`` after recording ``i - 1`` and its mode ``drift_mode`` has
the natural frequency ``f (1 - drift_per_recording * i)``: constant within a recording, so no single bag shows the
change. ``spread`` adds a recording-to-recording variation (operating point, temperature): every mode's frequency,
damping and gain times ``1 + spread * N(0, 1)``, drawn per recording. Its params file gives the estimator a short
start (2 s initialization, 1 s memories, a 2 s baseline window), so a 10 s recording is monitored for its last ~3 s.

:class:`Machine` describes other machines (rate, modes, memories, the fault logic's start-up: ``None`` keeps the
product's defaults, e.g. 3 memory lengths of settling and a baseline of 5 memory lengths).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

RATE_HZ = 1000.0
MODES = ((5.0, 0.05, 1.0), (20.0, 0.02, 0.2))
T0_NS = 1_750_000_000 * 10**9


def _yaml_float(v: float) -> str:
    """A float as YAML 1.1 reads a float (PyYAML takes ``1e-06`` for a string: ``1.0e-06``)."""
    text = repr(float(v))
    return text.replace("e", ".0e") if "e" in text and "." not in text else text


@dataclass(frozen=True)
class Machine:
    """A simulated open-loop machine and the params its recordings are diagnosed with."""

    rate_hz: float = RATE_HZ
    modes: tuple[tuple[float, float, float], ...] = MODES     # (natural frequency Hz, damping ratio, gain)
    memory_s: float = 1.0
    init_duration_s: float = 2.0
    settle_memory_lengths: float | None = 1.0                 # None: the product's default
    baseline_duration_s: float | None = 2.0                   # None: the product's default
    band_hz: tuple[float, float] = (0.5, 150.0)               # multisine lines, geometrically spaced
    noise_std: float = 0.01

    def params_yaml(self, extra_faults: dict[str, float] | None = None) -> str:
        """The node's params file for this machine (``extra_faults``: more ``faults.*`` entries)."""
        def floats(values: object) -> str:
            return "[" + ", ".join(_yaml_float(v) for v in values) + "]"   # type: ignore[attr-defined]

        faults = {"settle_memory_lengths": self.settle_memory_lengths,
                  "baseline_duration_s": self.baseline_duration_s, **(extra_faults or {})}
        lines = [f"# Simulated machine of additive_rsrivc_ros.sim.fleetsim: open loop, {self.rate_hz:g} Hz, modes at "
                 + ", ".join(f"{f:g}" for f, _, _ in self.modes) + " Hz.",
                 "/**/additive_rsrivc_monitor:", "  ros__parameters:", f"    loop_rate_hz: {_yaml_float(self.rate_hz)}",
                 "    closed_loop: false", "    modes:",
                 f"      natural_frequency_hz: {floats(m[0] for m in self.modes)}",
                 f"      damping_ratio: {floats(m[1] for m in self.modes)}",
                 f"      gain: {floats(m[2] for m in self.modes)}",
                 f"      memory_s: {floats([self.memory_s] * len(self.modes))}",
                 f"    init_duration_s: {_yaml_float(self.init_duration_s)}", "    publish_rate_hz: 10.0"]
        entries = [f"      {k}: {_yaml_float(v)}" for k, v in faults.items() if v is not None]
        return "\n".join(lines + (["    faults:", *entries] if entries else [])) + "\n"


DEFAULT_MACHINE = Machine()


def machine_params(path: str | Path, extra_faults: dict[str, float] | None = None, *,
                   machine: Machine = DEFAULT_MACHINE) -> Path:
    """Write the simulated machine's params file (``extra_faults``: more ``faults.*`` entries, e.g.
    ``{"min_change.natural_frequency": 0.0175}``) and return its path."""
    path = Path(path)
    path.write_text(machine.params_yaml(extra_faults), encoding="utf-8")
    return path


def recording_modes(index: int, *, machine: Machine = DEFAULT_MACHINE, drift_per_recording: float = 0.0,
                    drift_mode: int = 2, spread: float = 0.0, seed: int = 0) -> list[tuple[float, float, float]]:
    """The true (f, zeta, gain) of each mode in recording ``index`` (drift and recording-to-recording spread)."""
    rng = np.random.default_rng([int(seed), int(index), 1])
    out = []
    for i, (f, z, g) in enumerate(machine.modes):
        vary = 1.0 + spread * rng.standard_normal(3)
        drift = 1.0 - drift_per_recording * index if i + 1 == drift_mode else 1.0
        out.append((f * drift * vary[0], z * vary[1], g * vary[2]))
    return out


def write_recording(path: str | Path, index: int, *, drift_per_recording: float = 0.0, drift_mode: int = 2,
                    duration_s: float = 10.0, seed: int = 0, interval_s: float = 86400.0, spread: float = 0.0,
                    machine: Machine = DEFAULT_MACHINE) -> Path:
    """Simulate recording ``index`` of the machine and write it as an MCAP rosbag2 with its truth topics."""
    from ..io.bagio import write_bag
    from .simulate import PlantMode, multisine, simulate_modes, time_vector, white_noise

    rng = np.random.default_rng([int(seed), int(index)])
    t = time_vector(machine.rate_hz, duration_s)
    lo, hi = machine.band_hz
    lines = np.unique(np.rint(np.geomspace(lo, hi, 60) * 10.0)) / 10.0
    u = multisine(t, lines[lines > 0], 1.0, rng)
    modes = [PlantMode(f, z, g) for f, z, g in recording_modes(
        index, machine=machine, drift_per_recording=drift_per_recording, drift_mode=drift_mode, spread=spread,
        seed=seed)]
    sim = simulate_modes(modes, machine.rate_hz, u=u, noise=white_noise(t.size, machine.noise_std, rng), rng=rng)
    t0 = T0_NS + int(round(index * interval_s * 1e9))
    return write_bag(path, machine.rate_hz, sim.u, sim.y, None, truth_modal=sim.modal, t0_ns=t0,
                     custom_data={"additive_rsrivc.scenario": "fleetsim", "additive_rsrivc.seed": str(seed),
                                  "additive_rsrivc.recording": str(index)})


def write_machine_recordings(out_dir: str | Path, n: int, *, drift_per_recording: float = 0.0, drift_mode: int = 2,
                             duration_s: float = 10.0, seed: int = 0, extra_faults: dict[str, float] | None = None,
                             spread: float = 0.0, machine: Machine = DEFAULT_MACHINE, first: int = 0,
                             ) -> tuple[list[Path], Path]:
    """Recordings ``rec_<first>`` ... ``rec_<first + n - 1>`` and ``machine.yaml`` in ``out_dir``; returns (bags,
    params)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    bags = [write_recording(out / f"rec_{i:02d}", i, drift_per_recording=drift_per_recording, drift_mode=drift_mode,
                            duration_s=duration_s, seed=seed, spread=spread, machine=machine)
            for i in range(first, first + n)]
    return bags, machine_params(out / "machine.yaml", extra_faults, machine=machine)
