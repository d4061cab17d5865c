#!/usr/bin/env python3
"""The product against the alternatives a user would pick, on the product's own simulator (closed loop, known truth).

Needs the comparison packages, never a dependency of the product::

    pip install -r scripts/requirements-compare.txt     # pyOMA-2 (SSI-cov), sippy-unipi (N4SID)
    python scripts/compare_alternatives.py [--quick] [--seeds 3] [--seed 1]

Part 1, three records per plant (30 s, seeds 1-3; ``--quick`` one of 20 s): the modes found, their worst frequency and
damping errors against the truth, spurious modes and the compute time, for

- the product: ``core.modefind.find_modes`` (what ``rsrivc_identify --modes auto`` runs: the FRF's peaks, the order
  scan by held-out output error, the closed-loop additive SRIVC) on ``r, u, y`` at the loop rate;
- SSI-cov (pyOMA-2, output-only): ``y`` anti-aliased and decimated to about 1 kHz, ``br`` 40 block rows, orders up to
  39, pyOMA-2's soft criteria label the stable poles (the hard criteria on mode-shape phase are off: one sensor); its
  automatic clustering needs several channels (with one every preset found no pole), so the stabilization diagram is
  read as a user reads it: stable poles within 1 % in frequency that appear in at least half of the orders are one
  mode (median frequency and damping);
- N4SID (sippy-unipi, input-output ``u -> y``): the same decimated ``u, y``, horizon 40, order 2-16 by AIC; every
  complex pole pair of the identified ``A`` is a mode.

A found mode matches a true one within 5 % in frequency (nearest first, one to one); ``spurious``: found, matched to
none; errors are relative, the worst over the matched modes.

Part 2, tracking (plant B, 180 s; ``--quick`` 150 s): the 45 Hz mode's frequency drops by 3 % at 120 s (a step). The
product's recursive estimator ([RA-SRIVC] Algorithm 2, every mode's memory 5 s, and 2.5 s; started from the modes
the product found on the first 20 s) against SSI-cov on sliding windows of 5 s and 10 s, one every second
(``--quick``: 2 s), each window's estimate at its end (causal) and the stable-pole group nearest to the previous
estimate. Printed: the std of the frequency estimate over 30-120 s (stationary), the time after the step until the
estimate first crosses the middle of the step (-1.5 %), and the compute time per second of data.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import io
import logging
import math
import os
import sys
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("TQDM_DISABLE", "1")

import numpy as np  # noqa: E402

NEEDED = {"pyoma2": "pyOMA-2", "sippy_unipi": "sippy-unipi"}
MATCH = 0.05            # a found mode matches a true one within 5 % in frequency
STABLE_SHARE = 0.5      # SSI-cov: a stable-pole group in at least half of the orders is a mode
GROUP = 0.01            # ... stable poles within 1 % in frequency are one group
SSI_BR = 40
N4SID_HORIZON = 40
DECIMATED_HZ = 1000.0   # the alternatives get the data anti-aliased and decimated to about this rate


def missing_packages() -> list[str]:
    return [pip for mod, pip in NEEDED.items() if importlib.util.find_spec(mod) is None]


@dataclass(frozen=True)
class Case:
    name: str
    rate: float
    delay: int
    modes: tuple


def cases() -> list[Case]:
    from additive_rsrivc_ros.sim.simulate import PlantMode as M

    return [Case("A: 4 modes, pair 62/71 Hz, 4096 Hz", 4096.0, 2,
                 (M(18.0, 0.03, 1.0), M(62.0, 0.01, 0.2), M(71.0, 0.015, 0.15), M(240.0, 0.02, 0.05))),
            Case("B: 3 modes, 2000 Hz", 2000.0, 1, (M(9.0, 0.05, 1.0), M(45.0, 0.02, 0.2), M(160.0, 0.01, 0.05)))]


def record(case: Case, duration_s: float, seed: int, changes: tuple = ()) -> tuple:
    """``(sim, controller)``: the closed loop under a PI designed for the plant (``validate_autostart.py``'s rule),
    setpoint a 2 Hz square wave plus 5 % white dither, white output noise of 1 % of the output's std."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from validate_autostart import design_controller

    from additive_rsrivc_ros.sim.simulate import simulate_modes, square_wave, white_noise

    rng = np.random.default_rng(seed)
    ctrl = design_controller(list(case.modes), case.rate, case.delay)
    t = np.arange(int(duration_s * case.rate)) / case.rate
    r = square_wave(t, 2.0, 1.0) + white_noise(t.size, 0.05, rng)
    clean = simulate_modes(case.modes, case.rate, r=r, controller=ctrl, input_delay=case.delay, changes=changes)
    noise = white_noise(t.size, 0.01 * float(np.std(clean.y)), rng)
    sim = simulate_modes(case.modes, case.rate, r=r, controller=ctrl, input_delay=case.delay, noise=noise,
                         changes=changes, rng=rng)
    return sim, ctrl


def decimated(x: np.ndarray, rate: float) -> tuple[np.ndarray, float]:
    from scipy.signal import decimate

    q = max(1, int(round(rate / DECIMATED_HZ)))
    return (decimate(x, q, ftype="fir", zero_phase=True) if q > 1 else x), rate / q


# ------------------------------------------------------------------------------------------------- the methods
def product_modes(sim, ctrl, case: Case) -> np.ndarray:
    from additive_rsrivc_ros.core.identification.modefind import find_modes

    res = find_modes(sim.u, sim.y, case.rate, r=sim.r, controller=ctrl, input_delay=case.delay)
    return np.array([m[:2] for m in res.modal if m[0] > 0])


def ssi_cov_modes(y: np.ndarray, fs: float, br: int = SSI_BR) -> np.ndarray:
    """SSI-cov (pyOMA-2) and its stabilization diagram read automatically (module docstring)."""
    from pyoma2.algorithms import SSI
    from pyoma2.setup import SingleSetup

    setup = SingleSetup(y[:, None], fs=fs)
    alg = SSI(name="ssicov", method="cov", br=br, ordmax=br - 1, calc_unc=False,
              hc={"xi_max": 0.2, "mpc_lim": None, "mpd_lim": None, "CoV_max": None})
    setup.add_algorithms(alg)
    with warnings.catch_warnings(), contextlib.redirect_stdout(io.StringIO()):
        warnings.simplefilter("ignore")
        setup.run_by_name("ssicov")
    res = alg.result
    stable = (res.Lab == 1) & np.isfinite(res.Fn_poles) & (res.Fn_poles > 0)
    f, z = res.Fn_poles[stable], res.Xi_poles[stable]
    order = np.argsort(f)
    f, z = f[order], z[order]
    out, start = [], 0
    for k in range(1, f.size + 1):
        if k == f.size or f[k] > f[k - 1] * (1.0 + GROUP):
            if k - start >= STABLE_SHARE * res.Fn_poles.shape[1]:
                out.append((float(np.median(f[start:k])), float(np.median(z[start:k]))))
            start = k
    return np.array(out).reshape(-1, 2)


def n4sid_modes(u: np.ndarray, y: np.ndarray, fs: float) -> np.ndarray:
    """N4SID (sippy-unipi), order by AIC; every complex pole pair of ``A`` a mode."""
    from sippy_unipi import system_identification

    with warnings.catch_warnings(), contextlib.redirect_stdout(io.StringIO()):
        warnings.simplefilter("ignore")
        model = system_identification(y, u, "N4SID", SS_f=N4SID_HORIZON, SS_orders=[2, 16], IC="AIC",
                                      tsample=1.0 / fs)
    lam = np.linalg.eigvals(np.asarray(model.A))
    lam = lam[(np.abs(lam) > 1e-9) & (lam.imag > 1e-12)]
    s = np.log(lam.astype(complex)) * fs
    f, z = np.abs(s) / (2 * math.pi), -s.real / np.abs(s)
    order = np.argsort(f)
    return np.column_stack([f[order], z[order]])


# ------------------------------------------------------------------------------------------------- scoring
def match(found: np.ndarray, truth: np.ndarray) -> list[tuple[int, int]]:
    """One-to-one pairs ``(true index, found index)`` within :data:`MATCH` in frequency, nearest first."""
    pairs = sorted((abs(found[j, 0] / truth[i, 0] - 1.0), i, j) for i in range(len(truth)) for j in range(len(found)))
    used_i, used_j, out = set(), set(), []
    for d, i, j in pairs:
        if d <= MATCH and i not in used_i and j not in used_j:
            used_i.add(i)
            used_j.add(j)
            out.append((i, j))
    return out


def score(found: np.ndarray, truth: np.ndarray) -> dict:
    pairs = match(found, truth)
    ef = [abs(found[j, 0] / truth[i, 0] - 1.0) for i, j in pairs]
    ez = [abs(found[j, 1] / truth[i, 1] - 1.0) for i, j in pairs]
    return {"found": len(found), "matched": len(pairs), "spurious": len(found) - len(pairs),
            "df": 100 * max(ef) if ef else math.nan, "dz": 100 * max(ez) if ez else math.nan}


def accuracy_runs(duration_s: float, seed: int) -> list[tuple]:
    """``(plant, method, true modes, score, CPU s, failure)`` for each plant and method on one record."""
    rows = []
    for case in cases():
        sim, ctrl = record(case, duration_s, seed)
        truth = np.array([[m.natural_frequency_hz, m.damping_ratio] for m in case.modes])
        u_d, fs = decimated(sim.u, case.rate)
        y_d, _ = decimated(sim.y, case.rate)
        methods = (("product: find_modes (rsrivc_identify --modes auto)", product_modes, (sim, ctrl, case)),
                   ("SSI-cov (pyOMA-2, output-only)", ssi_cov_modes, (y_d, fs)),
                   ("N4SID (sippy-unipi, u -> y)", n4sid_modes, (u_d, y_d, fs)))
        for name, run, run_args in methods:
            t0 = time.process_time()
            try:
                found = run(*run_args)
                why = ""
            except Exception as exc:  # noqa: BLE001 - a method that fails is a row, not the end of the comparison
                found, why = np.zeros((0, 2)), f"{type(exc).__name__}: {exc}"[:60]
            rows.append((case.name, name, len(truth), score(found, truth), time.process_time() - t0, why))
    return rows


def accuracy_rows(duration_s: float, seeds: list[int]) -> list[dict]:
    """Per plant and method over the seeds' records: modes matched and found, spurious, the worst errors, the
    median CPU time and the failures."""
    runs = [row for seed in seeds for row in accuracy_runs(duration_s, seed)]
    out: dict[tuple[str, str], dict] = {}
    for plant, name, n_true, s, cpu, why in runs:
        a = out.setdefault((plant, name), {"plant": plant, "method": name, "true": 0, "matched": 0, "found": 0,
                                           "spurious": 0, "df": math.nan, "dz": math.nan, "cpu": [], "failed": []})
        a["true"] += n_true
        a["matched"] += s["matched"]
        a["found"] += s["found"]
        a["spurious"] += s["spurious"]
        a["df"] = float(np.nanmax([a["df"], s["df"]]))
        a["dz"] = float(np.nanmax([a["dz"], s["dz"]]))
        a["cpu"].append(cpu)
        if why:
            a["failed"].append(why)
    return list(out.values())


# ------------------------------------------------------------------------------------------------- tracking
STEP_AT_S = 120.0
STEP = -0.03
TRACKED = 1                  # plant B's 45 Hz mode
MEMORIES_S = (5.0, 2.5)       # the tracker's memory: the brief's 5 s, and 2.5 s (it crosses in about 1.4 memories)


def track_recursive(sim, ctrl, case: Case, memory_s: float,
                    init_s: float = 20.0) -> tuple[np.ndarray, np.ndarray, float, float]:
    """``(t, f_hat, cpu s of the tracking, cpu s of the start)``: the product's recursive estimator, every mode's
    memory ``memory_s``, started from the modes the product finds on the first ``init_s`` seconds (its offline
    initialization on the same samples)."""
    from additive_rsrivc_ros.core.estimation.recursive import RecursiveAdditiveSRIVC
    from additive_rsrivc_ros.core.model import SubmodelStructure, theta_from_modal

    n0 = int(init_s * case.rate)
    w = slice(0, n0)
    c0 = time.process_time()
    from additive_rsrivc_ros.core.identification.modefind import find_modes

    found = find_modes(sim.u[w], sim.y[w], case.rate, r=sim.r[w], controller=ctrl, input_delay=case.delay)
    thetas = [theta_from_modal(*m) for m in found.modal]
    lam = np.full(len(thetas), 1.0 - 1.0 / (memory_s * case.rate))
    est = RecursiveAdditiveSRIVC([SubmodelStructure()] * len(thetas), thetas, case.rate, forgetting=lam,
                                 controller=ctrl, input_delay=case.delay)
    est.initialize(sim.r[w], sim.u[w], sim.y[w])
    c1 = time.process_time()
    tr = est.update(sim.r[n0:], sim.u[n0:], sim.y[n0:], trace=True)
    cpu = time.process_time() - c1
    f_all = 1.0 / (2 * math.pi * np.sqrt(tr[:, :, 1]))
    f0 = case.modes[TRACKED].natural_frequency_hz
    k = int(np.argmin(np.abs(np.nanmedian(f_all[: int(case.rate)], axis=0) - f0)))  # the tracked mode's column
    t = np.arange(n0, sim.y.size) / case.rate
    return t, f_all[:, k], cpu, c1 - c0


def track_ssi(y: np.ndarray, rate: float, f0: float, window_s: float, hop_s: float) -> tuple[np.ndarray, ...]:
    """``(t, f_hat, cpu s)``: SSI-cov on sliding windows ending at ``t``; per window the mode nearest to the previous
    estimate (first: to ``f0``) within :data:`MATCH`, else NaN."""
    y_d, fs = decimated(y, rate)
    n_w, hop = int(window_s * fs), int(hop_s * fs)
    ts, fs_hat = [], []
    prev = f0
    c0 = time.process_time()
    for end in range(n_w, y_d.size + 1, hop):
        modes = ssi_cov_modes(y_d[end - n_w:end], fs)
        near = modes[np.abs(modes[:, 0] / prev - 1.0) <= MATCH] if len(modes) else modes
        f = float(near[np.argmin(np.abs(near[:, 0] - prev)), 0]) if len(near) else math.nan
        prev = f if math.isfinite(f) else prev
        ts.append(end / fs)
        fs_hat.append(f)
    return np.array(ts), np.array(fs_hat), time.process_time() - c0


def tracking_stats(t: np.ndarray, f: np.ndarray, f0: float) -> tuple[float, float, float]:
    """``(std over 30-120 s [Hz], mean bias there [%], crossing time after the step [s])``: the first time the
    estimate falls below the middle of the step (NaN: never)."""
    quiet = (t >= 30.0) & (t < STEP_AT_S) & np.isfinite(f)
    after = np.flatnonzero((t >= STEP_AT_S) & (f < f0 * (1.0 + 0.5 * STEP)))
    cross = float(t[after[0]] - STEP_AT_S) if after.size else math.nan
    return float(np.std(f[quiet])), 100.0 * float(np.mean(f[quiet]) / f0 - 1.0), cross


def tracking_rows(duration_s: float, hop_s: float, seed: int) -> list[tuple]:
    from additive_rsrivc_ros.sim.simulate import ModalChange

    case = cases()[1]
    sim, ctrl = record(case, duration_s, seed, changes=(ModalChange(TRACKED, "frequency", STEP, STEP_AT_S),))
    f0 = case.modes[TRACKED].natural_frequency_hz
    rows = []
    for memory in MEMORIES_S:
        t, f, cpu, start = track_recursive(sim, ctrl, case, memory)
        rows.append((f"product: recursive tracker, memory {memory:g} s (start: modes found and initialized on the "
                     f"first 20 s in {start:.1f} s CPU)", *tracking_stats(t, f, f0), cpu, duration_s - 20.0))
    for window in (5.0, 10.0):
        t, f, cpu = track_ssi(sim.y, case.rate, f0, window, hop_s)
        miss = int(np.sum(~np.isfinite(f)))
        name = f"SSI-cov, {window:g} s windows every {hop_s:g} s" + (f" ({miss} windows without it)" if miss else "")
        rows.append((name, *tracking_stats(t, f, f0), cpu, duration_s))
    return rows


# ------------------------------------------------------------------------------------------------- output
def _n(v: float, fmt: str) -> str:
    return "–" if not math.isfinite(v) else format(v, fmt)


def print_tables(acc: list[dict], trk: list[tuple], args: argparse.Namespace) -> None:
    print(f"## Modes found, {len(args.seeds)} closed-loop record(s) of {args.duration:g} s per plant (seeds "
          f"{', '.join(map(str, args.seeds))}); errors vs truth: the worst matched mode of all records\n")
    print("| plant | method | modes matched / true (found) | spurious | max freq. error | max damping error | "
          "median CPU time |")
    print("|---|---|---|---|---|---|---|")
    for a in acc:
        found = f"{a['matched']} of {a['true']} ({a['found']})"
        if a["failed"]:
            found += f", {len(a['failed'])} failed: {a['failed'][0]}"
        print(f"| {a['plant']} | {a['method']} | {found} | {a['spurious']} | {_n(a['df'], '.3g')} % | "
              f"{_n(a['dz'], '.3g')} % | {float(np.median(a['cpu'])):.1f} s |")
    print(f"\n## Tracking the 45 Hz mode of plant B ({args.track_duration:g} s, seed {args.seed}, step {STEP:+.0%} "
          f"at {STEP_AT_S:g} s)\n")
    print("| method | std of f over 30-120 s | bias there | crossing time after the step | CPU per s of data |")
    print("|---|---|---|---|---|")
    for name, sd, bias, cross, cpu, dur in trk:
        print(f"| {name} | {_n(sd, '.3g')} Hz | {_n(bias, '+.3f')} % | {_n(cross, '.2f')} s | "
              f"{1000.0 * cpu / dur:.1f} ms |")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="shorter records, SSI windows every 2 s")
    ap.add_argument("--seeds", type=int, default=None, help="records per plant (default 3, --quick 1)")
    ap.add_argument("--seed", type=int, default=1, help="first seed (the tracking record's)")
    args = ap.parse_args(argv)
    missing = missing_packages()
    if missing:
        print(f"compare_alternatives: missing {', '.join(missing)}: pip install -r scripts/requirements-compare.txt",
              file=sys.stderr)
        return 2
    logging.disable(logging.WARNING)
    args.duration = 20.0 if args.quick else 30.0
    args.track_duration = 150.0 if args.quick else 180.0
    hop = 2.0 if args.quick else 1.0
    t0 = time.perf_counter()
    args.seeds = list(range(args.seed, args.seed + (args.seeds or (1 if args.quick else 3))))
    acc = accuracy_rows(args.duration, args.seeds)
    trk = tracking_rows(args.track_duration, hop, args.seed)
    print_tables(acc, trk, args)
    print(f"\n(wall time {time.perf_counter() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
