#!/usr/bin/env python
"""Is the published std honest after the start? RMS of (estimate - truth) / reported std per parameter.

Beam (000 §6 / NOTES: K = 2 of 4 plant modes, 4096 Hz, delay 4, memories 2.44 s / 0.244 s, stationary), offline
initialization on the first 5 s, then the recursion; for both ``estimator.p0_policy`` values. An honest std gives
values near 1 (below 1 for a smooth estimate); thousands mean the std claims far more than the data hold.

Usage: ``python scripts/study_std_calibration.py [--seed 0] [--duration 40]``
"""

from __future__ import annotations

import argparse
import os
import sys

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import numpy as np  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from validate_recursive import BEAM_MODES, beam_controller  # noqa: E402

from additive_rsrivc_ros.core.model import SubmodelStructure, theta_from_modal  # noqa: E402
from additive_rsrivc_ros.core.recursive import P0_POLICIES, RecursiveAdditiveSRIVC  # noqa: E402
from additive_rsrivc_ros.core.simulate import simulate_modes  # noqa: E402

WINDOWS_S = (0.0, 2.5, 5.0, 10.0, 20.0, np.inf)   # after the start of the recursion


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--duration", type=float, default=40.0)
    args = ap.parse_args(argv)
    rate = 4096.0
    n = int(args.duration * rate)
    t = np.arange(n) / rate
    rng = np.random.default_rng(args.seed)
    ctrl = beam_controller(rate)
    r = 1e-3 * np.sign(np.sin(2 * np.pi * 2.0 * t + 1e-9))
    sim = simulate_modes(BEAM_MODES, rate, r=r, controller=ctrl, input_delay=4, noise=2e-6 * rng.standard_normal(n))
    truth = [theta_from_modal(m.natural_frequency_hz, m.damping_ratio, m.gain) for m in BEAM_MODES[:2]]
    guess = [theta_from_modal(m.natural_frequency_hz * f, m.damping_ratio * 1.2, m.gain * 0.9)
             for m, f in zip(BEAM_MODES[:2], (1.1, 0.9), strict=True)]
    lam = np.array([1 - 1 / (2.44 * rate), 1 - 1 / (0.244 * rate)])
    n0, chunk = int(5 * rate), int(0.05 * rate)
    print("RMS (estimate - truth) / reported std of [a1, a2, b0] per mode, by time after the start of the recursion")
    for policy in P0_POLICIES:
        est = RecursiveAdditiveSRIVC([SubmodelStructure()] * 2, guess, rate, forgetting=lam, controller=ctrl,
                                     input_delay=4, p0_policy=policy)
        est.initialize(r[:n0], sim.u[:n0], sim.y[:n0])
        z, times = [], []
        for k in range(n0, n - chunk + 1, chunk):
            est.update(r[k:k + chunk], sim.u[k:k + chunk], sim.y[k:k + chunk])
            sd = [np.sqrt(np.diag(c)) for c in est.covariances]
            z.append([(th - tr) / s for th, tr, s in zip(est.thetas, truth, sd, strict=True)])
            times.append((k + chunk - n0) / rate)
        z, times = np.array(z), np.array(times)
        print(f"\np0_policy = {policy}")
        for a, b in zip(WINDOWS_S[:-1], WINDOWS_S[1:], strict=True):
            sel = (times > a) & (times <= b)
            if not sel.any():
                continue
            rms = np.sqrt(np.mean(z[sel] ** 2, axis=0))
            print(f"  ({a:4.1f}, {min(b, times[-1]):4.1f}] s   mode 1 {np.array2string(rms[0], precision=3)}"
                  f"   mode 2 {np.array2string(rms[1], precision=3)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
