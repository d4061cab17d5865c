#!/usr/bin/env python3
"""Good guesses on weakly excited closed-loop data: does the offline
initialization help or hurt the tracking?

The [RA-SRIVC] §5 loop (modes at 0.32, 0.80 and 3.18 Hz) with reference lines at 2 and 5 rad/s only -- on modes 1 and 2,
none on mode 3 -- plus a weak white dither (std ``--dither``). Guesses are ``--offset`` off (frequency x (1 +
offset), damping x (1 + 5 offset), gain x (1 - 3 offset)). Per seed the estimator runs on the same data with
``estimator.init_method`` ``auto`` with the guesses as a prior (``estimator.guess_spread``, default), ``auto`` without
(``guess_spread`` 0: the fit replaces the guesses when it explains the initialization data better, as before issue
12's prior), ``none`` (the guesses as they are, with the parameter-scaled P(0)) and the prior with that P(0)
(``estimator.p0_policy: relative``: the same start values, the adaptation of ``none``); printed: the RMS relative error
of each mode's natural frequency and damping over the tracking (from the end of the initialization plus one memory
length), paired per seed, and the initialization's message.

    python scripts/study_weak_start.py [--seeds 5] [--duration 600] [--offset 0.015] [--dither 0.2]
"""

from __future__ import annotations

import argparse
import math
import sys

import numpy as np

from additive_rsrivc_ros.config import MonitorConfig, load_config
from additive_rsrivc_ros.core.estimation.recursive import RecursiveAdditiveSRIVC
from additive_rsrivc_ros.sim import plants
from additive_rsrivc_ros.sim.scenarios import config_dir
from additive_rsrivc_ros.sim.simulate import simulate_modes, sum_of_sines, time_vector, white_noise


def simulate(seed: int, duration: float, dither: float):
    cfg = load_config(config_dir() / "paper_example.yaml")
    rng = np.random.default_rng([seed, 12])
    t = time_vector(cfg.loop_rate_hz, duration)
    r = sum_of_sines(t, [1.0, 1.0], [2.0, 5.0]) + white_noise(t.size, dither, rng)
    sim = simulate_modes(plants.PAPER_MODES, cfg.loop_rate_hz, r=r, controller=cfg.controller,
                         noise=white_noise(t.size, 0.1, rng), rng=rng)
    return cfg, sim


VARIANTS = {"prior": ("auto", None, None), "no prior": ("auto", 0.0, None), "none": ("none", None, None),
            "prior, P0 rel": ("auto", None, "relative")}


def track(cfg: MonitorConfig, sim, variant: str, offset: float) -> tuple[np.ndarray, str]:
    """(K, 2) RMS relative error of (frequency, damping) over the tracking, and the init message."""
    p = dict(cfg.params)
    p["estimator.init_method"], spread, p0 = VARIANTS[variant]
    if spread is not None:
        p["estimator.guess_spread"] = spread
    if p0 is not None:
        p["estimator.p0_policy"] = p0
    p["modes.natural_frequency_hz"] = [f * (1 + offset) for f in p["modes.natural_frequency_hz"]]
    p["modes.damping_ratio"] = [z * (1 + 5 * offset) for z in p["modes.damping_ratio"]]
    p["modes.gain"] = [g * (1 - 3 * offset) for g in p["modes.gain"]]
    c = MonitorConfig.from_params(p)
    rate = c.loop_rate_hz
    est = RecursiveAdditiveSRIVC.from_config(c)
    ni = int(c.init_duration_s * rate)
    est.initialize(sim.r[:ni], sim.u[:ni], sim.y[:ni])
    start = ni + int(max(m.memory_s for m in c.modes) * rate)
    err, step = [], int(rate)
    for k in range(ni, sim.u.size, step):
        est.update(sim.r[k:k + step], sim.u[k:k + step], sim.y[k:k + step])
        if k + step >= start:
            m = est.modal()[:, :2]
            err.append(m / sim.modal[:c.K, min(k + step, sim.u.size) - 1, :2] - 1.0)
    e = np.asarray(err)
    return np.sqrt(np.mean(e**2, axis=0)), est.init_message


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--duration", type=float, default=600.0)
    ap.add_argument("--offset", type=float, default=0.015)
    ap.add_argument("--dither", type=float, default=0.2)
    args = ap.parse_args(argv)
    rows: dict[str, list[np.ndarray]] = {v: [] for v in VARIANTS}
    for seed in range(args.seeds):
        cfg, sim = simulate(seed, args.duration, args.dither)
        for method in rows:
            rms, msg = track(cfg, sim, method, args.offset)
            rows[method].append(rms)
            print(f"seed {seed} {method:13s}: RMS error f " + " ".join(f"{100 * v:6.2f}%" for v in rms[:, 0]) +
                  " | zeta " + " ".join(f"{100 * v:6.1f}%" for v in rms[:, 1]) + f"   [{msg[:90]}]")
            sys.stdout.flush()
    worst = math.nan
    for num, den in (("prior", "no prior"), ("prior", "none"), ("prior, P0 rel", "none")):
        ratio = np.asarray(rows[num]) / np.asarray(rows[den])
        print(f"\npaired ratio {num} / {den} of the RMS error (median over seeds, worst seed):")
        for i in range(ratio.shape[1]):
            print(f"  mode {i + 1}: frequency {np.median(ratio[:, i, 0]):.2f} (worst {ratio[:, i, 0].max():.2f}), "
                  f"damping {np.median(ratio[:, i, 1]):.2f} (worst {ratio[:, i, 1].max():.2f})")
        worst = float(np.max(np.median(ratio, axis=0)))
        print(f"  largest median ratio {worst:.2f} ({'no worse' if worst <= 1.0 + 1e-9 else 'WORSE'} than {den})")
    return 0 if math.isfinite(worst) else 1


if __name__ == "__main__":
    sys.exit(main())
