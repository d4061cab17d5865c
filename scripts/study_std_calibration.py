#!/usr/bin/env python
"""Is the published std calibrated? Coverage of +-2 sigma per case and quantity.

For every case the recursive estimator (offline start on the first ``init_s``, then [RA-SRIVC] Algorithm 2) runs over a
stationary simulated plant with known truth; every ``check_s`` the published ``modal()`` (natural frequency,
damping, gain and their std, the same numbers the node puts on /diagnostics and ~/modes and rsrivc_diagnose
writes) is compared with the truth. Coverage = fraction of check instants at which ``|estimate - truth| <= 2
std``; a calibrated Gaussian std gives 95.4 %. The band printed next to it is 95.4 % +- 2 binomial sd for
``n_eff = seeds * T / (2 memory)`` effectively independent samples (the error of a forgetting estimator decorrelates
over about two memory lengths). A NaN std counts as not covered (and is counted). ``mean z`` (signed mean of
``(estimate - truth)/std``) far from 0 shows bias; ``sigma^2 P`` is the coverage of the former std
``sqrt(sigma^2 P_bar)`` (the former published std) for comparison.

Cases (--case, default all):

* ``broadband_open``: [A-SRIVC] §5.2 plant ``3/(0.25p^2+0.25p+1) + 1/(0.025p^2+0.01p+1)``, 20 Hz, white input var 1,
  white output noise var 0.01, memory 25 s.
* ``broadband_closed``: the same plant in closed loop with the corrected PID (erratum 1 in docs/DESIGN.md), white
  reference var 1.
* ``narrow_closed``: [RA-SRIVC] §5 (3 modes, 4 reference lines), stationary, memory 50 s: identifiability limited by
  the excitation , bias expected.
* ``beam``: [RA-SRIVC] §6, K = 2 of 4 modes, 4096 Hz, 2 Hz square wave, memories 2.44 / 0.244 s (mode 2's memory
  is below its decay time 1/(zeta omega) = 0.28 s, and modes 3-4 are not modelled): bias expected.

Windows: ``start`` = the first memory of each mode after the recursion starts, ``steady`` = the rest.

Usage: ``python scripts/study_std_calibration.py [--seeds 10] [--quick] [--case broadband_open ...]``
(``--quick``: 3 seeds, shorter runs, beam 1 seed).
"""

from __future__ import annotations

import argparse
import os
import sys
from dataclasses import dataclass

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import numpy as np  # noqa: E402

from additive_rsrivc_ros.core.estimation.recursive import RecursiveAdditiveSRIVC  # noqa: E402
from additive_rsrivc_ros.core.model import (  # noqa: E402
    SubmodelStructure,
    modal_from_theta,
    modal_std,
    theta_from_modal,
)
from additive_rsrivc_ros.sim.plants import BEAM_THETAS, PAPER_PID, beam_controller  # noqa: E402
from additive_rsrivc_ros.sim.simulate import PlantMode, simulate_modes  # noqa: E402

NOMINAL = 0.9545   # P(|N(0,1)| <= 2)
QUANTITIES = ("f", "zeta", "gain")
BB_MODES = [PlantMode(*modal_from_theta(np.array([0.25, 0.25, 3.0]))),
            PlantMode(*modal_from_theta(np.array([0.01, 0.025, 1.0])))]
PAPER_MODES = [PlantMode(2.0 / (2 * np.pi), 0.25, 3.0), PlantMode(5.0 / (2 * np.pi), 0.025, 0.5),
               PlantMode(20.0 / (2 * np.pi), 0.1, 1.0)]
BEAM_MODES = [PlantMode(*modal_from_theta(th)) for th in BEAM_THETAS]


@dataclass(frozen=True)
class Case:
    name: str
    rate: float
    modes: list            # plant modes (truth)
    n_est: int             # estimated modes (the first n_est of the plant)
    memory_s: tuple
    duration_s: float
    init_s: float
    check_s: float
    closed: bool
    excitation: str        # "white", "paper", "square"
    noise_std: float
    delay: int = 0


CASES = {
    "broadband_open": Case("broadband_open", 20.0, BB_MODES, 2, (25.0, 25.0), 800.0, 25.0, 1.0, False, "white", 0.1),
    "broadband_closed": Case("broadband_closed", 20.0, BB_MODES, 2, (25.0, 25.0), 800.0, 25.0, 1.0, True, "white",
                             0.1),
    "narrow_closed": Case("narrow_closed", 20.0, PAPER_MODES, 3, (50.0, 50.0, 50.0), 1000.0, 50.0, 1.0, True,
                          "paper", 0.1),
    "beam": Case("beam", 4096.0, BEAM_MODES, 2, (2.44, 0.244), 25.0, 5.0, 0.05, True, "square", 2e-6, 4),
}


def _controller(case: Case):
    if not case.closed:
        return None
    return beam_controller(case.rate) if case.excitation == "square" else PAPER_PID


def simulate_case(case: Case, seed: int, duration_s: float):
    """Simulated data of one seed: (r or None, u, y, truth (n_est, 3))."""
    rng = np.random.default_rng(seed)
    n = int(round(duration_s * case.rate))
    t = np.arange(n) / case.rate
    if case.excitation == "white":
        drive = rng.standard_normal(n)
    elif case.excitation == "paper":
        drive = 3 * np.sin(0.005 * t) + np.sin(2 * t) + np.sin(5 * t) + np.sin(17.5 * t)
    else:
        drive = 1e-3 * np.sign(np.sin(2 * np.pi * 2.0 * t + 1e-9))
    noise = case.noise_std * rng.standard_normal(n)
    ctrl = _controller(case)
    if case.closed:
        sim = simulate_modes(case.modes, case.rate, r=drive, controller=ctrl, input_delay=case.delay, noise=noise)
        r = drive
    else:
        sim = simulate_modes(case.modes, case.rate, u=drive, input_delay=case.delay, noise=noise)
        r = None
    truth = np.array([[m.natural_frequency_hz, m.damping_ratio, m.gain] for m in case.modes[:case.n_est]])
    return r, sim.u, sim.y, truth


def run_seed(case: Case, seed: int, duration_s: float) -> dict:
    """One run: per check instant the published modal (K, 6) and time since the start of the recursion."""
    r, u, y, truth = simulate_case(case, seed, duration_s)
    rng = np.random.default_rng(1000 + seed)
    guess = [theta_from_modal(f * (1 + rng.uniform(-0.05, 0.05)), z * (1 + rng.uniform(-0.2, 0.2)),
                              g * (1 + rng.uniform(-0.1, 0.1))) for f, z, g in truth]
    lam = np.array([1.0 - 1.0 / (m * case.rate) for m in case.memory_s[:case.n_est]])
    est = RecursiveAdditiveSRIVC([SubmodelStructure()] * case.n_est, guess, case.rate, forgetting=lam,
                                 controller=_controller(case), input_delay=case.delay, filter_policy="auto")
    n0 = int(round(case.init_s * case.rate))
    est.initialize(None if r is None else r[:n0], u[:n0], y[:n0])
    chunk = max(int(round(case.check_s * case.rate)), 1)
    modal, old, times, problems = [], [], [], 0
    for k in range(n0, u.size - chunk + 1, chunk):
        est.update(None if r is None else r[k:k + chunk], u[k:k + chunk], y[k:k + chunk])
        modal.append(est.modal())
        old.append([modal_std(th, c, st) for th, c, st in zip(est.thetas, est.information_covariances,
                                                               est.structures, strict=True)])
        times.append((k + chunk - n0) / case.rate)
        problems += sum(1 for p in est.health.covariance_problems if p)
    return {"modal": np.array(modal), "old_std": np.array(old), "t": np.array(times), "truth": truth,
            "problems": problems, "init": est.init_message}


def coverage_table(case: Case, runs: list[dict]) -> list[dict]:
    """Rows per (window, mode, quantity): coverage, RMS z, NaN fraction, n_eff and its binomial band."""
    rows = []
    for window in ("start", "steady"):
        for i in range(case.n_est):
            mem = case.memory_s[i]
            inside, zs, old_in, nan, t_span = [], [], [], 0, 0.0
            for run in runs:
                t = run["t"]
                sel = (t <= mem) if window == "start" else (t > mem)
                if not sel.any():
                    continue
                t_span += float(t[sel].max() - t[sel].min() + case.check_s)
                m = run["modal"][sel, i, :]
                z = (m[:, :3] - run["truth"][i]) / m[:, 3:]
                nan += int(np.sum(~np.isfinite(z)))
                inside.append(np.abs(z) <= 2.0)       # NaN -> False (not covered)
                zs.append(z)
                old_in.append(np.abs(m[:, :3] - run["truth"][i]) <= 2.0 * run["old_std"][sel, i, :])
            if not inside:
                continue
            inside_a = np.concatenate(inside)
            z_a = np.concatenate(zs)
            old_a = np.concatenate(old_in)
            n_eff = max(t_span / (2.0 * mem), 1.0)
            half = 2.0 * np.sqrt(NOMINAL * (1 - NOMINAL) / n_eff)
            for q, name in enumerate(QUANTITIES):
                cov = float(np.mean(inside_a[:, q]))
                zq = z_a[:, q][np.isfinite(z_a[:, q])]
                rows.append({"window": window, "mode": i + 1, "quantity": name, "coverage": cov,
                             "rms_z": float(np.sqrt(np.mean(zq ** 2))) if zq.size else float("nan"),
                             "mean_z": float(np.mean(zq)) if zq.size else float("nan"),
                             "old_coverage": float(np.mean(old_a[:, q])),
                             "nan_fraction": float(np.mean(~np.isfinite(z_a[:, q]))), "n_eff": n_eff,
                             "band": (NOMINAL - half, NOMINAL + half)})
    return rows


def print_table(case: Case, rows: list[dict], seeds: int, duration_s: float, problems: int) -> None:
    print(f"\n== {case.name}: {seeds} seed(s) x {duration_s:g} s, {case.rate:g} Hz, memories "
          f"{', '.join(f'{m:g}' for m in case.memory_s[:case.n_est])} s; covariance problems flagged: {problems}")
    print(f"{'window':<7} {'mode':>4} {'qty':<5} {'coverage':>9} {'RMS z':>7} {'mean z':>7} {'NaN':>5} {'n_eff':>6}  "
          f"{'binomial band':>15}  {'sigma^2 P':>9}  verdict")
    for row in rows:
        lo, hi = row["band"]
        cov = row["coverage"]
        if 0.90 <= cov <= 0.98:
            verdict = "calibrated (90-98 %)"
        elif cov < 0.90:
            verdict = "OVERCONFIDENT: errors beyond the std (bias/transient)" if row["rms_z"] > 1.2 else \
                "under-covers"
        else:
            verdict = "conservative (std too large)"
        print(f"{row['window']:<7} {row['mode']:>4} {row['quantity']:<5} {100 * cov:8.1f}% {row['rms_z']:7.2f} "
              f"{row['mean_z']:7.2f} {100 * row['nan_fraction']:4.0f}% {row['n_eff']:6.0f}  [{100 * lo:5.1f}, "
              f"{100 * hi:5.1f}] %  {100 * row['old_coverage']:8.1f}%  {verdict}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10, help="seeds per case (the beam uses --beam-seeds)")
    ap.add_argument("--beam-seeds", type=int, default=3)
    ap.add_argument("--quick", action="store_true", help="3 seeds, half-length runs, 1 beam seed")
    ap.add_argument("--case", action="append", choices=sorted(CASES), help="case(s) to run (default all)")
    args = ap.parse_args(argv)
    names = args.case or list(CASES)
    for name in names:
        case = CASES[name]
        seeds = (1 if args.quick else args.beam_seeds) if name == "beam" else (3 if args.quick else args.seeds)
        duration = case.duration_s if not args.quick or name == "beam" else 0.5 * case.duration_s
        runs = [run_seed(case, seed, duration) for seed in range(seeds)]
        rows = coverage_table(case, runs)
        print_table(case, rows, seeds, duration, sum(r["problems"] for r in runs))
    return 0


if __name__ == "__main__":
    sys.exit(main())
