"""Simulated recordings of one machine over time, for ``rsrivc_fleet``'s tests, benchmark and documentation figure.

The machine: an open-loop plant at 1 kHz with two modes (5 Hz, zeta 0.05, gain 1; 20 Hz, zeta 0.02, gain 0.2),
driven by a random-phase multisine (0.5-150 Hz, rms 1) with white output noise (std 0.01). Recording ``i``
starts ``interval_s`` after recording ``i - 1`` and its mode ``drift_mode`` has the natural frequency
``f (1 - drift_per_recording * i)``: constant within a recording, so no single bag shows the change. The
params file :data:`MACHINE_PARAMS` gives the estimator a short start (2 s initialization, 1 s memories, a 2 s
baseline window), so a 10 s recording is monitored for its last ~3 s.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

RATE_HZ = 1000.0
MODES = ((5.0, 0.05, 1.0), (20.0, 0.02, 0.2))
T0_NS = 1_750_000_000 * 10**9
MACHINE_PARAMS = """\
# Simulated machine of additive_rsrivc_ros.sim.fleetsim: open loop, 1 kHz, two modes (5 Hz and 20 Hz).
/**/additive_rsrivc_monitor:
  ros__parameters:
    loop_rate_hz: 1000.0
    closed_loop: false
    modes:
      natural_frequency_hz: [5.0, 20.0]
      damping_ratio: [0.05, 0.02]
      gain: [1.0, 0.2]
      memory_s: [1.0, 1.0]
    init_duration_s: 2.0
    publish_rate_hz: 10.0
    faults:
      settle_memory_lengths: 1.0
      baseline_duration_s: 2.0
{extra}"""


def machine_params(path: str | Path, extra_faults: dict[str, float] | None = None) -> Path:
    """Write the simulated machine's params file (``extra_faults``: more ``faults.*`` entries, e.g.
    ``{"min_change.natural_frequency": 0.0175}``) and return its path."""
    extra = "".join(f"      {k}: {v!r}\n" for k, v in (extra_faults or {}).items())
    path = Path(path)
    path.write_text(MACHINE_PARAMS.format(extra=extra), encoding="utf-8")
    return path


def write_recording(path: str | Path, index: int, *, drift_per_recording: float = 0.0, drift_mode: int = 2,
                    duration_s: float = 10.0, seed: int = 0, interval_s: float = 86400.0) -> Path:
    """Simulate recording ``index`` of the machine and write it as an MCAP rosbag2 with its truth topics."""
    from ..bagio import write_bag
    from .simulate import PlantMode, multisine, simulate_modes, time_vector, white_noise

    rng = np.random.default_rng([int(seed), int(index)])
    t = time_vector(RATE_HZ, duration_s)
    lines = np.unique(np.rint(np.geomspace(0.5, 150.0, 60) * 10.0)) / 10.0
    u = multisine(t, lines[lines > 0], 1.0, rng)
    modes = [PlantMode(f * (1.0 - drift_per_recording * index if i + 1 == drift_mode else 1.0), z, g)
             for i, (f, z, g) in enumerate(MODES)]
    sim = simulate_modes(modes, RATE_HZ, u=u, noise=white_noise(t.size, 0.01, rng), rng=rng)
    t0 = T0_NS + int(round(index * interval_s * 1e9))
    return write_bag(path, RATE_HZ, sim.u, sim.y, None, truth_modal=sim.modal, t0_ns=t0,
                     custom_data={"additive_rsrivc.scenario": "fleetsim", "additive_rsrivc.seed": str(seed),
                                  "additive_rsrivc.recording": str(index)})


def write_machine_recordings(out_dir: str | Path, n: int, *, drift_per_recording: float = 0.0, drift_mode: int = 2,
                             duration_s: float = 10.0, seed: int = 0, extra_faults: dict[str, float] | None = None,
                             ) -> tuple[list[Path], Path]:
    """``n`` recordings ``rec_00``, ``rec_01``, ... and ``machine.yaml`` in ``out_dir``; returns (bags, params)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    bags = [write_recording(out / f"rec_{i:02d}", i, drift_per_recording=drift_per_recording, drift_mode=drift_mode,
                            duration_s=duration_s, seed=seed) for i in range(n)]
    return bags, machine_params(out / "machine.yaml", extra_faults)
