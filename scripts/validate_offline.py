#!/usr/bin/env python3
"""Monte Carlo validation of the offline estimators; prints tables, returns 0 if every check passes.

Cases (run all, or pick with --case):
  cl52    [A-SRIVC] §5.2 closed loop: h = 0.05 s, N = 10000, white r (var 1), white noise (var 0.01), corrected PID,
          start beta*(1 + U(-0.05, 0.05)), tol 1e-7. Additive CLSRIVC vs unfactored SRIVC and CLSRIVC (split
          into the additive form). Checks: all converge, |bias| <= 0.3 sigma (with the Monte Carlo error of
          the mean added), MSE within 1.3x of the reference figures, additive beats SRIVC on a12 and a22.
          Also printed: the asymptotic variances of this experiment (optimal-instrument IV bound, [A-SRIVC] Theorem 1;
          Cramer-Rao bound of the direct approach), MSE against them, and which reference figures lie below
          the Cramer-Rao bound.
  bcd     [BCD-SRIVC] case study 1 (open loop): h = 0.005 s, N = 10000, white u (var 1), white noise (var 1), start
          within 10 %. MSE of the equivalent unfactored parameters vs the BCD row of [BCD-SRIVC] Table 1.
  uns     [UNS-SRIVC] §7.1 unstable plant (-0.5p + 1)/(p^2 - 0.1414 p + 2) under the discrete PID, h = 0.1, N = 15000,
          r var 1, noise var 0.05; LSSVF-uns init; SRIVC-uns and CLSRIVC-uns vs [UNS-SRIVC] Table 1.
  int     [UNS-SRIVC] §7.4 integrator plant (p - 2)/(p (p + 1)), h = 0.1, N = 15000, noise var 0.2, open loop
          (u var 1) and closed loop (C = -0.249 - 2.07 (1 - q^-1), r var 1); solutions 1 (monic) and 2
          (forced integrator) vs [UNS-SRIVC] Table 4.
  speed   time of a K = 2 additive CLSRIVC on N = 10000 (target < 1 s).

Usage: python scripts/validate_offline.py [--runs N] [--case cl52 bcd uns int speed] [--seed S] [--paths J ...]
(default runs: 50 per case, 300 for bcd)

``--paths J ...``: the same cases on other rounding paths as well (every fit's output times ``1 + J 1e-12``, as
another CPU's arithmetic would perturb it; J = 0 is this CPU's path and is always run first). Each path prints its
own tables, then one line per case and path: the fits whose estimate moved from path 0's by more than 1 % of the
Monte Carlo spread of that method's estimates (a fit near a tipping point lands on another optimum), the largest
move in those units, the convergence flips and the fits that stopped at another iteration. The speed case runs on
path 0 only.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import numpy as np  # noqa: E402

from additive_rsrivc_ros.core.controller import DiscreteController  # noqa: E402
from additive_rsrivc_ros.core.identification.offline import identify as _identify_path0  # noqa: E402
from additive_rsrivc_ros.core.identification.offline import to_unfactored  # noqa: E402
from additive_rsrivc_ros.core.model import SubmodelStructure  # noqa: E402
from additive_rsrivc_ros.sim.independent import (  # noqa: E402
    MODE,
    PAPER_THETAS,
    PID_DEN,
    PID_NUM,
    cl52_reference_mse,
    second_order_gradient_covariance,
    simulate,
)
from additive_rsrivc_ros.sim.plants import (  # noqa: E402
    INT_CONTROLLER_DEN,
    INT_CONTROLLER_NUM,
    INT_MONIC_THETA,
    INT_STRUCTURE,
    INT_THETA,
)

NAMES_52 = ["a11", "a12", "b10", "a21", "a22", "b20"]
VERDICT_NOTES: dict[str, str] = {}
#: the rounding path (``--paths``): the output scale of every fit and, when not None, the log of every fit's
#: ``(method, beta, converged, iterations)`` in call order (the same on every path: no random draw depends on a fit)
PATH: dict = {"scale": 1.0, "log": None}
#: a fit whose estimate moved between rounding paths by more than this fraction of the Monte Carlo spread of its
#: method's estimates (per parameter) is near a tipping point; stopping at another iteration moves it by ~1e-4
MOVED_SPREAD = 0.01


def identify(u, y, *args, **kwargs):
    """:func:`..core.offline.identify` on the current rounding path (``y`` times ``PATH['scale']``: 1.0 leaves it
    bit for bit), logging the result when ``PATH['log']`` is a list."""
    res = _identify_path0(u, y * PATH["scale"], *args, **kwargs)
    if PATH["log"] is not None:
        PATH["log"].append((str(kwargs.get("method", "default")), np.array(res.beta, dtype=float),
                            bool(res.converged), int(res.iterations)))
    return res


def _table(title: str, names: list[str], rows: dict[str, list[float]], fmt: str = "{:>11.3e}") -> None:
    print(f"\n{title}")
    print(f"{'':<26}" + "".join(f"{n:>11}" for n in names))
    for label, vals in rows.items():
        print(f"{label:<26}" + "".join(fmt.format(v) for v in vals))


def case_cl52(runs: int, seed: int) -> bool:
    truth = np.concatenate(PAPER_THETAS)
    h, N = 0.05, 10000
    ctrl = DiscreteController(PID_NUM, PID_DEN)
    methods = ["additive-clsrivc", "srivc", "clsrivc"]
    est = {m: [] for m in methods}
    conv = {m: 0 for m in methods}
    rng = np.random.default_rng(seed)
    t0 = time.perf_counter()
    for _ in range(runs):
        r = rng.standard_normal(N)
        v = np.sqrt(0.01) * rng.standard_normal(N)
        u, y = simulate(PAPER_THETAS, [MODE, MODE], h, r=r, controller=(PID_NUM, PID_DEN), noise=v)
        start = [t * (1 + rng.uniform(-0.05, 0.05, 3)) for t in PAPER_THETAS]
        for m in methods:
            res = identify(u, y, 1 / h, [MODE, MODE], start, r=r, controller=ctrl, method=m, tol=1e-7)
            conv[m] += res.converged
            est[m].append(res.beta)
    print(f"\n=== [A-SRIVC] §5.2 closed loop, {runs} runs, N = {N} ({time.perf_counter() - t0:.1f} s) ===")
    ref = cl52_reference_mse()
    bound_iv, bound_cr = cl52_asymptotic_variances(h, N, ctrl_tf=(PID_NUM, PID_DEN), seed=seed + 1)
    rows = {"truth": list(truth), "reference MSE": list(ref), "IV bound ([A-SRIVC] Thm 1)": list(bound_iv),
            "Cramer-Rao (direct)": list(bound_cr), "reference/Cramer-Rao": list(ref / bound_cr)}
    for m in methods:
        e = np.array(est[m])
        bias = e.mean(0) - truth
        sd = e.std(0, ddof=1)
        mse = ((e - truth) ** 2).mean(0)
        rows[f"{m} bias"] = list(bias)
        rows[f"{m} sigma"] = list(sd)
        rows[f"{m} MSE"] = list(mse)
        rows[f"{m} MSE/ref"] = list(mse / ref)
        rows[f"{m} MSE/IV bound"] = list(mse / bound_iv)
        print(f"{m}: converged {conv[m]}/{runs}")
    _table("parameters", NAMES_52, rows)
    e = np.array(est["additive-clsrivc"])
    bias, sd = e.mean(0) - truth, e.std(0, ddof=1)
    mse = ((e - truth) ** 2).mean(0)
    # strict checks decide; the Monte Carlo allowances (2.5 standard errors of a mean, 2 relative standard errors
    # sqrt(2/runs) of an MSE) are printed beside them to tell a real shortfall from run-to-run scatter
    mc = 1 + 2 * np.sqrt(2 / runs)
    bias_ok = np.all(np.abs(bias) <= 0.3 * sd)
    bias_mc = np.all(np.abs(bias) <= 0.3 * sd + 2.5 * sd / np.sqrt(runs))
    mse_ok = np.all(mse <= 1.3 * ref)
    mse_mc = np.all(mse <= 1.3 * ref * mc)
    bound_ok = np.all(mse <= 1.3 * bound_iv * mc)
    # the reference figures are 50-run MSEs themselves: below the bound by more than their own two relative
    # standard errors, they cannot be an unbiased estimator's MSE of this experiment
    below_cr = [n for n, x, b in zip(NAMES_52, ref, bound_cr, strict=True) if x < b / (1 + 2 * np.sqrt(2 / 50))]
    s = np.array(est["srivc"])
    mse_s = ((s - truth) ** 2).mean(0)
    parsimony = mse[1] < mse_s[1] and mse[4] < mse_s[4]
    all_conv = conv["additive-clsrivc"] == runs
    print(f"checks: all converged {all_conv}; |bias| <= 0.3 sigma {bias_ok} (with MC allowance {bias_mc}); "
          f"MSE <= 1.3 ref {mse_ok} (worst ratio {np.max(mse / ref):.2f}; with MC allowance {mse_mc}); "
          f"MSE <= 1.3 x IV bound with MC allowance {bound_ok} (worst ratio {np.max(mse / bound_iv):.2f}); "
          f"additive beats SRIVC on a12 ({mse[1]:.3g} vs {mse_s[1]:.3g}) and a22 ({mse[4]:.3g} vs {mse_s[4]:.3g}): "
          f"{parsimony}")
    if below_cr:
        print(f"note: the reference MSE of {', '.join(below_cr)} lies below the Cramer-Rao bound of this experiment "
              "by more than the Monte Carlo error of its own 50 runs: no unbiased estimator reaches 1.3x of it")
        over = [n for n, x, rf in zip(NAMES_52, mse, ref, strict=True) if x > 1.3 * rf]
        if bound_ok and set(over) <= set(below_cr):
            VERDICT_NOTES["cl52"] = (f"fails the reference only on {', '.join(over)}, whose figures lie below the "
                                     "Cramer-Rao bound; within 1.3x of the bound on every parameter")
    return bool(all_conv and bias_ok and mse_ok and parsimony)


def cl52_asymptotic_variances(h: float, N: int, ctrl_tf, seed: int, n_long: int = 200_000):
    """Asymptotic variances at N samples of [a11, a12, b10, a21, a22, b20] for the [A-SRIVC] §5.2 experiment: the
    optimal-instrument IV bound ([A-SRIVC] Theorem 1 / Corollary 1; gradients driven by S_uo r) and the Cramer-Rao bound
    of the direct approach (gradients driven by the measured input, fed-back noise included)."""
    rng = np.random.default_rng(seed)
    r = rng.standard_normal(n_long)
    v = np.sqrt(0.01) * rng.standard_normal(n_long)
    u_clean, _ = simulate(PAPER_THETAS, [MODE, MODE], h, r=r, controller=ctrl_tf)
    u_meas, _ = simulate(PAPER_THETAS, [MODE, MODE], h, r=r, controller=ctrl_tf, noise=v)
    iv = np.diag(second_order_gradient_covariance(PAPER_THETAS, h, u_clean, 0.01)) / N
    cr = np.diag(second_order_gradient_covariance(PAPER_THETAS, h, u_meas, 0.01)) / N
    return iv, cr


def case_bcd(runs: int, seed: int) -> bool:
    truth = [np.array([0.25, 0.25, 3.0]), np.array([0.01, 0.0025, 1.0])]
    h, N = 0.005, 10000
    tu, su = to_unfactored(truth, [MODE, MODE])
    # [BCD-SRIVC] Table 1 order: a1..a4, b0, b1, b2 (b3 = 0 by structure)
    ref = np.array([3.41e-4, 3.45e-5, 1.62e-8, 2.16e-10, 2.41e-2, 4.45e-3, 9.04e-5])
    rng = np.random.default_rng(seed)
    est, conv = [], 0
    t0 = time.perf_counter()
    for _ in range(runs):
        u = rng.standard_normal(N)
        v = rng.standard_normal(N)
        u, y = simulate(truth, [MODE, MODE], h, u=u, noise=v)
        start = [t * (1 + rng.uniform(-0.1, 0.1, 3)) for t in truth]
        res = identify(u, y, 1 / h, [MODE, MODE], start, method="bcd-srivc", tol=1e-7, max_iterations=100)
        conv += res.converged
        est.append(to_unfactored(res.thetas, [MODE, MODE])[0])
    e = np.array(est)
    mse = ((e - tu) ** 2).mean(0)
    cr = _bcd_cramer_rao(truth, h, N, seed + 1)
    print(f"\n=== [BCD-SRIVC] case study 1 (BCD, open loop), {runs} runs ({time.perf_counter() - t0:.1f} s), "
          f"converged {conv}/{runs} ===")
    _table("equivalent unfactored parameters", ["a1", "a2", "a3", "a4", "b0", "b1", "b2"],
           {"truth": list(tu), "[BCD-SRIVC] Table 1 BCD MSE": list(ref), "Cramer-Rao": list(cr),
            "Table 1/Cramer-Rao": list(ref / cr), "MSE": list(mse), "MSE/ref": list(mse / ref),
            "MSE/Cramer-Rao": list(mse / cr)})
    ok = np.all(mse <= 1.3 * ref)
    mc = np.all(mse <= 1.3 * ref * (1 + 2 * np.sqrt(2 / runs)))
    print(f"checks: MSE <= 1.3 x [BCD-SRIVC] Table 1 {ok} (worst ratio {np.max(mse / ref):.2f}); within 1.3 x plus "
          f"two Monte Carlo standard errors of a {runs}-run MSE (x{1 + 2 * np.sqrt(2 / runs):.2f}): {mc}")
    return bool(ok and conv == runs)


def _bcd_cramer_rao(truth, h: float, N: int, seed: int) -> np.ndarray:
    """Cramer-Rao bound at N samples of the equivalent unfactored parameters [a1..a4, b0..b2] of [BCD-SRIVC] case study
    1 (white input and noise of unit variance): the additive bound mapped by the Jacobian of ``to_unfactored``."""
    u = np.random.default_rng(seed).standard_normal(400_000)
    cov = second_order_gradient_covariance(truth, h, u, 1.0, skip=4000) / N
    x0 = np.concatenate(truth)

    def unf(x):
        return to_unfactored([x[:3], x[3:]], [MODE, MODE])[0]

    jac = np.empty((7, 6))
    for j in range(6):
        d = np.zeros(6)
        d[j] = 1e-6 * abs(x0[j])
        jac[:, j] = (unf(x0 + d) - unf(x0 - d)) / (2 * d[j])
    return np.diag(jac @ cov @ jac.T)


def _uns_truth():
    # G = (-0.5 p + 1)/(p^2 + 2 xi wn p + wn^2), wn^2 = 2, xi = -0.05 -> anti-monic: divide by wn^2
    wn2, xi = 2.0, -0.05
    a1 = 2 * xi * np.sqrt(wn2) / wn2
    return np.array([a1, 1 / wn2, 1 / wn2, -0.5 / wn2])


def case_uns(runs: int, seed: int) -> bool:
    st = SubmodelStructure(n=2, m=1)
    truth = _uns_truth()
    h, N = 0.1, 15000
    num = (0.0272 + 2.54e-5 + 7.29, -(0.0272 + 2 * 7.29), 7.29)  # PID in q^-1 over (1 - q^-1)
    ctrl = DiscreteController(num, (1.0, -1.0))
    rng = np.random.default_rng(seed)
    methods = ["lssvf-uns", "srivc-uns", "clsrivc-uns"]
    est = {m: [] for m in methods}
    conv = {m: 0 for m in methods}
    t0 = time.perf_counter()
    for _ in range(runs):
        r = rng.standard_normal(N)
        v = np.sqrt(0.05) * rng.standard_normal(N)
        u, y = simulate([truth], [st], h, r=r, controller=(num, (1.0, -1.0)), noise=v)
        start = truth.copy()
        start[0] += 0.02 * rng.standard_normal()
        start[1] += 0.1 * rng.standard_normal()
        res0 = identify(u, y, 1 / h, [st], [start], r=r, controller=ctrl, method="lssvf-uns")
        est["lssvf-uns"].append(res0.beta)
        conv["lssvf-uns"] += 1
        for m in methods[1:]:
            res = identify(u, y, 1 / h, [st], res0.thetas, r=r, controller=ctrl, method=m, tol=1e-8)
            conv[m] += res.converged
            if res.converged:
                est[m].append(res.beta)
    print(f"\n=== [UNS-SRIVC] §7.1 unstable plant, {runs} runs ({time.perf_counter() - t0:.1f} s) ===")
    ref_sd = {"srivc-uns": np.array([1.49e-3, 1.00e-3, 3.82e-3, 1.17e-3]),
              "clsrivc-uns": np.array([1.53e-3, 1.12e-3, 3.96e-3, 2.10e-3])}
    # the paper's a2 = 0.5 etc. are for the monic-denominator scaling (p^2 + ...); Table 1 lists
    # a1 = -0.0707, a2 = 0.5, b0 = 0.5, b1 = -0.25, i.e. our anti-monic theta.
    rows = {"truth": list(truth)}
    ok = True
    for m in methods:
        e = np.array(est[m])
        rows[f"{m} mean"] = list(e.mean(0))
        rows[f"{m} sd"] = list(e.std(0, ddof=1))
        print(f"{m}: converged {conv[m]}/{runs}")
        if m in ref_sd:
            rows[f"{m} sd/Table 1"] = list(e.std(0, ddof=1) / ref_sd[m])
            within = np.all(np.abs(e.mean(0) - truth) <= e.std(0, ddof=1))
            sd_ok = np.all(e.std(0, ddof=1) <= 1.5 * ref_sd[m] * (1 + 2 / np.sqrt(2 * runs)))
            print(f"{m}: mean within 1 sd {within}; sd <= 1.5 x Table 1 {sd_ok}")
            ok &= bool(within and sd_ok and conv[m] >= runs - max(1, runs // 100))
    _table("parameters [a1, a2, b0, b1]", ["a1", "a2", "b0", "b1"], rows)
    return ok


def case_int(runs: int, seed: int) -> bool:
    h, N = 0.1, 15000
    # G = (p - 2)/(p (p + 1)): solution 2 structure B/(p A), A = 1 + p, B = -2 + p
    st2, th2 = INT_STRUCTURE, INT_THETA
    # solution 1 (monic): A = p^2 + a1 p + a0 with a0 = 0, a1 = 1; B = b0 + b1 p = -2 + p
    st1, th1 = SubmodelStructure(n=2, m=1), INT_MONIC_THETA  # monic layout [a0, a1, b0, b1]
    cnum, cden = INT_CONTROLLER_NUM, INT_CONTROLLER_DEN
    ctrl = DiscreteController(cnum, cden)
    rng = np.random.default_rng(seed)
    out = {}
    t0 = time.perf_counter()
    for loop in ("open", "closed"):
        for sol in (1, 2):
            out[(loop, sol)] = []
    conv = dict.fromkeys(out, 0)
    for _ in range(runs):
        v = np.sqrt(0.2) * rng.standard_normal(N)
        for loop in ("open", "closed"):
            if loop == "open":
                u = rng.standard_normal(N)
                u, y = simulate([th2], [st2], h, u=u, noise=v)
                r = c = None
            else:
                r = rng.standard_normal(N)
                u, y = simulate([th2], [st2], h, r=r, controller=(cnum, cden), noise=v)
                c = ctrl
            pre = "srivc" if loop == "open" else "clsrivc"
            s1 = th1.copy()
            s1[0] += 0.1 * rng.standard_normal()
            s1[1] += 0.1 * rng.standard_normal()
            res1 = identify(u, y, 1 / h, [st1], [s1], r=r, controller=c, method=f"{pre}-uns-monic", tol=1e-8)
            conv[(loop, 1)] += res1.converged
            out[(loop, 1)].append(res1.beta)
            s2 = th2 * (1 + 0.1 * rng.standard_normal(3))
            res2 = identify(u, y, 1 / h, [st2], [s2], r=r, controller=c, method=f"{pre}-uns", tol=1e-8)
            conv[(loop, 2)] += res2.converged
            a1p, bp = res2.beta[0], res2.beta[1:]          # B'/(p (1 + a1' p)) = (B'/a1') / (p^2 + p/a1')
            out[(loop, 2)].append(np.concatenate(([0.0, 1.0 / a1p], bp / a1p)))   # monic [a0 = 0, a1, b0, b1]
    print(f"\n=== [UNS-SRIVC] §7.4 integrator plant, {runs} runs ({time.perf_counter() - t0:.1f} s) ===")
    ref = {("open", 1): ([4.43e-4, 1.08e-4, 4.30e-4, 5.08e-4], 2.31e-12),
           ("open", 2): ([1.65e-4, 1.10e-4, 4.37e-4, 5.04e-4], 0.0),
           ("closed", 1): ([-3.73e-3, 1.50e-3, 3.27e-3, 1.35e-3], 7.28e-7),
           ("closed", 2): ([-3.42e-3, 1.47e-3, 3.24e-3, 1.33e-3], 0.0)}
    truth = th1
    rows = {}
    ok = True
    for key, vals in out.items():
        e = np.array(vals)
        bias = e.mean(0) - truth
        mse = ((e - truth) ** 2).mean(0)
        name = f"{'SRIVC' if key[0] == 'open' else 'CLSRIVC'}-uns-{key[1]}"
        rows[f"{name} bias"] = list(bias)
        rows[f"{name} MSE"] = list(mse)
        ref_mse = np.array([ref[key][1], ref[key][0][1], ref[key][0][2], ref[key][0][3]])
        rows[f"{name} Table 4 MSE"] = list(ref_mse)
        print(f"{name}: converged {conv[key]}/{runs}")
        # "of the order of Table 4": MSE of a1, b0, b1 within a factor 3 (MC error included)
        ok &= bool(np.all(mse[1:] <= 3 * ref_mse[1:] * (1 + 2 * np.sqrt(2 / runs))) and conv[key] == runs)
    _table("parameters [a0, a1, b0, b1] (monic)", ["a0", "a1", "b0", "b1"], rows)
    print(f"checks: all converged and MSE(a1, b0, b1) within 3x of Table 4: {ok}")
    return ok


def case_speed(seed: int) -> bool:
    h, N = 0.05, 10000
    rng = np.random.default_rng(seed)
    r = rng.standard_normal(N)
    u, y = simulate(PAPER_THETAS, [MODE, MODE], h, r=r, controller=(PID_NUM, PID_DEN),
                    noise=0.1 * rng.standard_normal(N))
    ctrl = DiscreteController(PID_NUM, PID_DEN)
    start = [t * 1.05 for t in PAPER_THETAS]
    identify(u, y, 1 / h, [MODE, MODE], start, r=r, controller=ctrl)  # compile / warm up
    times = []
    for _ in range(3):
        t0 = time.perf_counter()
        res = identify(u, y, 1 / h, [MODE, MODE], start, r=r, controller=ctrl)
        times.append(time.perf_counter() - t0)
    best = min(times)
    print(f"\n=== speed: K = 2 additive CLSRIVC, N = {N}: {best:.3f} s ({res.iterations} iterations, "
          f"{1e3 * best / max(res.iterations, 1):.1f} ms/iteration); target < 1 s: {best < 1.0} ===")
    return best < 1.0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=None,
                    help="Monte Carlo runs of every case (default: 50, and 300 for bcd, whose reference is a 500-run "
                         "table: a 50-run MSE scatters by 20 %%)")
    ap.add_argument("--seed", type=int, default=2024)
    ap.add_argument("--case", nargs="+", default=["speed", "cl52", "bcd", "uns", "int"],
                    choices=["speed", "cl52", "bcd", "uns", "int"])
    ap.add_argument("--paths", type=int, nargs="+", default=None, metavar="J",
                    help="also run on these rounding paths (outputs x (1 + J 1e-12)) and compare every fit with "
                         "path 0's")
    a = ap.parse_args(argv)
    paths = [0] + [j for j in dict.fromkeys(a.paths or []) if j != 0]
    results: dict[str, bool] = {}
    logs: dict[tuple[str, int], list] = {}
    verdicts: dict[tuple[str, int], bool] = {}
    for j in paths:
        PATH["scale"] = 1.0 + j * 1e-12
        if len(paths) > 1:
            print(f"\n##### rounding path {j} (outputs x (1 + {j}e-12)) #####")
        for c in a.case:
            if c == "speed":
                if j == 0:
                    results[c] = case_speed(a.seed)
                continue
            runs = a.runs if a.runs is not None else (300 if c == "bcd" else 50)
            PATH["log"] = logs[(c, j)] = []
            ok = {"cl52": case_cl52, "bcd": case_bcd, "uns": case_uns, "int": case_int}[c](runs, a.seed)
            PATH["log"] = None
            verdicts[(c, j)] = ok
            results[c] = results.get(c, True) and ok
    if len(paths) > 1:
        _print_path_comparison(logs, verdicts, paths)
    print("\nsummary: " + ", ".join(f"{k}: {'PASS' if v else 'FAIL'}" for k, v in results.items()))
    for k, note in VERDICT_NOTES.items():
        if not results.get(k, True):
            print(f"  {k}: {note}")
    return 0 if all(results.values()) else 1


def _print_path_comparison(logs: dict, verdicts: dict, paths: list[int]) -> None:
    """Per case and rounding path: the verdict, and how many fits moved from path 0's by more than MOVED_SPREAD of
    their method's Monte Carlo spread (path 0's sample standard deviation per parameter), the largest move in those
    units, the convergence flips and the fits that stopped at another iteration."""
    print(f"\n=== rounding paths: every fit against path 0's (moved: by more than {MOVED_SPREAD:g} x the Monte Carlo "
          "spread of its method's estimates) ===")
    print(f"{'case':<6}{'path':>5}{'verdict':>9}{'fits':>6}{'moved':>7}{'largest move [spread]':>23}"
          f"{'conv. flips':>13}{'other iters':>13}")
    for case in dict.fromkeys(c for c, _ in logs):
        base = logs[(case, 0)]
        spread = {m: np.std([b for mm, b, _, _ in base if mm == m], axis=0, ddof=1)
                  for m in dict.fromkeys(m for m, _, _, _ in base)}
        for j in paths:
            log = logs[(case, j)]
            if [m for m, *_ in log] != [m for m, *_ in base]:
                print(f"{case:<6}{j:>5}  fit sequences differ ({len(log)} against {len(base)} fits)")
                continue
            moves = [float(np.max(np.abs(b - b0) / np.maximum(spread[m], 1e-300))) if b.shape == b0.shape else np.inf
                     for (m, b, _, _), (_, b0, _, _) in zip(log, base, strict=True)]
            moved = sum(not v <= MOVED_SPREAD for v in moves)
            flips = sum(c != c0 for (_, _, c, _), (_, _, c0, _) in zip(log, base, strict=True))
            iters = sum(i != i0 for (_, _, _, i), (_, _, _, i0) in zip(log, base, strict=True))
            print(f"{case:<6}{j:>5}{'PASS' if verdicts[(case, j)] else 'FAIL':>9}{len(log):>6}{moved:>7}"
                  f"{max(moves, default=0.0):>23.2e}{flips:>13}{iters:>13}")


if __name__ == "__main__":
    sys.exit(main())
