#!/usr/bin/env python3
"""Attach to a moving rigid body: the monitor starts at many phases of the ``rigid_body`` scenario.

The plant ``1/p^2`` + 8 Hz + 25 Hz modes under PD control follows a 0.5 Hz square-wave setpoint, so at any attach
time its position and velocity are not zero. For each attach time the estimator (offline initialization over
``init_duration_s``, then the recursion) runs on the rest of the record; printed per phase: position and velocity of
the rigid body at the attach time, the largest relative error of (frequency, gain) over the modes and of the
damping at the end, and the stability projections. The start from rest (t0 = 0) is the reference row.

    python scripts/study_rigid_attach.py [--phases 20] [--duration 60] [--offset 0.1] [--open-loop] [--seed 0]
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from additive_rsrivc_ros.config import MonitorConfig
from additive_rsrivc_ros.core.estimation.recursive import RecursiveAdditiveSRIVC
from additive_rsrivc_ros.sim.scenarios import build


def attach_errors(sd, t0: float, offset: float, open_loop: bool, init_method: str = "auto") -> dict[str, float]:
    """Run the estimator from ``t0`` on; relative errors (%) at the end against the truth, guesses ``offset`` off."""
    p = dict(sd.config.params)
    p["estimator.init_method"] = init_method
    p["modes.natural_frequency_hz"] = [f * (1 + offset) for f in p["modes.natural_frequency_hz"]]
    p["modes.damping_ratio"] = [z * (1 + 2 * offset) for z in p["modes.damping_ratio"]]
    p["modes.gain"] = [g * (1 - offset) for g in p["modes.gain"]]
    if open_loop:
        p["closed_loop"] = False
    cfg = MonitorConfig.from_params(p)
    rate = cfg.loop_rate_hz
    n0 = int(round(t0 * rate))
    r, u, y = sd.r[n0:], sd.u[n0:], sd.y[n0:]
    est = RecursiveAdditiveSRIVC.from_config(cfg)
    ni = int(cfg.init_duration_s * rate)
    est.initialize(r[:ni], u[:ni], y[:ni])
    est.update(r[ni:], u[ni:], y[ni:])
    m, truth = est.modal(), sd.truth[:, -1, :]
    rel = np.abs(m[:, :3] - truth) / np.where(truth == 0, 1.0, np.abs(truth)) * 100.0
    return {"freq_gain": float(np.nanmax(rel[:, [0, 2]])), "damping": float(np.nanmax(rel[1:, 1])),
            "projections": int(np.sum(est.health.projections)), "init": est.init_message}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--phases", type=int, default=20)
    ap.add_argument("--duration", type=float, default=60.0, help="seconds of data after each attach time")
    ap.add_argument("--offset", type=float, default=0.1, help="guesses this far off (frequency +, damping +2x, gain -)")
    ap.add_argument("--open-loop", action="store_true", help="estimate with closed_loop false (instrument z = u)")
    ap.add_argument("--init-method", default="auto")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)
    period = 2.0   # the setpoint's square wave (0.5 Hz)
    sd = build("rigid_body", duration_s=a.duration + 2 * period, seed=a.seed, fault_time_s=None)
    rate = sd.rate_hz
    rows = [0.0] + [period * (k + 0.5) / a.phases + 0.013 for k in range(a.phases)]
    print(f"rigid_body, {'open' if a.open_loop else 'closed'} loop, guesses {a.offset:+.0%} off, init "
          f"{a.init_method}, {a.duration:g} s after each attach time, noise std {sd.parameters.get('noise_std')}")
    print(f"{'attach s':>9} {'y(t0)':>9} {'dy/dt':>9} {'max err f,gain %':>17} {'max err zeta %':>15} {'proj':>5}")
    worst, ref = 0.0, None
    for t0 in rows:
        k = int(round(t0 * rate))
        dy = (sd.y[k + 1] - sd.y[k - 1]) * rate / 2 if k > 0 else 0.0
        e = attach_errors(sd, t0, a.offset, a.open_loop, a.init_method)
        ref = e if ref is None else ref
        if t0 > 0:
            worst = max(worst, e["freq_gain"])
        print(f"{t0:9.3f} {sd.y[k]:9.4f} {dy:9.4f} {e['freq_gain']:17.4g} {e['damping']:15.4g} {e['projections']:5d}")
    print(f"worst attach in motion: {worst:.4g} % (start from rest {ref['freq_gain']:.4g} %)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
