"""The compiled per-report numbers (core/estimation/report_numbers.py) against the numpy functions they replace.

References: model.modal_from_theta and model.modal_std (delta method), recursive.covariance_problem (LAPACK
eigvalsh), np.linalg.svd for the IV condition number. Tolerances are rounding bounds: a sum computed in another
order differs by at most a few eps x the sum of its terms' magnitudes (a variance ``J C J^T`` whose terms cancel
differs relatively by more than eps); backward-stable eigen and singular value algorithms agree within a few
n eps ||A||, so the condition number within ~eps x cond^2 relative.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from additive_rsrivc_ros.core.estimation import report_numbers as rn
from additive_rsrivc_ros.core.estimation.recursive import COVARIANCE_REL_TOL, covariance_problem
from additive_rsrivc_ros.core.model import SubmodelStructure, modal_from_theta, modal_jacobian, modal_std

SECOND, RIGID1, RIGID2 = 0, 1, 2


def _structure(kind: int) -> SubmodelStructure:
    return SubmodelStructure(2, 0, 0) if kind == 0 else SubmodelStructure(0, 0, kind)


def _reference(kind, theta, P, S, sig2):
    """The numbers as the estimator computed them with numpy before they were compiled."""
    out = {"cov": [], "info": [], "modal": [], "info_rel": [], "cond": []}
    for i, k in enumerate(kind):
        s = _structure(int(k))
        nt, nk = s.n_theta, (3 if k == 0 else 1 + int(k))
        p = P[i, :nk, :nk]
        with np.errstate(all="ignore"):
            c = (p @ S[i, :nk, :nk] @ p.T)[:nt, :nt]
        out["cov"].append(sig2 * 0.5 * (c + c.T))
        pi = P[i, :nt, :nt]
        out["info"].append(sig2 * 0.5 * (pi + pi.T))
    out["problems"] = [covariance_problem(c) for c in out["cov"]]
    out["info_problems"] = [covariance_problem(c) for c in out["info"]]
    for i, k in enumerate(kind):
        s = _structure(int(k))
        th = theta[i, :s.n_theta]
        row = np.full(6, np.nan)
        row[:3] = modal_from_theta(th, s)
        if not out["problems"][i]:
            row[3:] = modal_std(th, out["cov"][i], s)
        out["modal"].append(row)
        rel = math.nan
        if not out["info_problems"][i]:
            with np.errstate(all="ignore"):
                r = np.abs(modal_std(th, out["info"][i], s) / row[:3])
            known = [v for v in ((float(r[0]) if s.n == 2 else 0.0), float(r[2])) if not math.isnan(v)]
            rel = max(known) if known else math.nan
        out["info_rel"].append(rel)
        dinv = 1.0 / np.maximum(np.abs(th), 1e-300)
        with np.errstate(all="ignore"):
            m = dinv[:, None] * P[i, :s.n_theta, :s.n_theta] * dinv[None, :]
        cond = math.nan
        if np.all(np.isfinite(m)):
            sv = np.linalg.svd(m, compute_uv=False)
            with np.errstate(all="ignore"):
                cond = float(sv[0] / sv[-1])
            cond = math.inf if math.isnan(cond) else cond
        out["cond"].append(cond)
    return out


def _compiled(kind, theta, P, S, sig2):
    K = kind.size
    cov, info = np.zeros((K, 3, 3)), np.zeros((K, 3, 3))
    problem, info_problem = np.zeros(K, dtype=np.int64), np.zeros(K, dtype=np.int64)
    modal, info_rel, cond = np.empty((K, 6)), np.empty(K), np.empty(K)
    rn.report_numbers(kind, theta, P, S, sig2, COVARIANCE_REL_TOL, cov, info, problem, info_problem, modal, info_rel,
                      cond)
    return cov, info, [rn.PROBLEM_NAMES[p] for p in problem], [rn.PROBLEM_NAMES[p] for p in info_problem], modal, \
        info_rel, cond


def _close(a, b, rtol):
    a, b = np.asarray(a, float), np.asarray(b, float)
    assert np.array_equal(np.isnan(a), np.isnan(b)), (a, b)
    assert np.array_equal(np.isinf(a), np.isinf(b)), (a, b)
    fin = np.isfinite(a)
    assert np.all(np.abs(a[fin] - b[fin]) <= rtol * np.maximum(np.abs(a[fin]), np.abs(b[fin]))), (a, b)


EPS = np.finfo(float).eps


def _close_std(a, b, absvar):
    """Stds whose variances differ by at most 64 eps x the sum of the magnitudes of their terms (``absvar``): each side
    is within (2 n + 1) u of the exact sandwich and a few u more from its Jacobian (n = 3, u = eps / 2), whatever
    the summation order or fused multiply-adds a compiler or CPU chooses, so 64 eps holds with a margin."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    assert np.array_equal(np.isnan(a), np.isnan(b)), (a, b)
    fin = np.isfinite(a)
    assert np.all(np.abs(a[fin] ** 2 - b[fin] ** 2) <= 64 * EPS * absvar[fin] + 1e-300), (a, b)


def _abs_var(kind, theta, cov):
    """``diag(|J| |C| |J|^T)``: the magnitude of the terms of each delta-method variance."""
    s = _structure(int(kind))
    with np.errstate(all="ignore"):
        jac = np.abs(modal_jacobian(theta[:s.n_theta], s))
        return np.einsum("ij,jk,ik->i", jac, np.abs(cov), jac)


def _spd(rng, n, cond=1e3):
    q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    return q @ np.diag(np.geomspace(1.0, 1.0 / cond, n) * rng.uniform(0.5, 2.0)) @ q.T


def _state(rng, kind, how):
    K = len(kind)
    theta = np.zeros((K, 3))
    P, S = np.zeros((K, 3, 3)), np.zeros((K, 3, 3))
    for i, k in enumerate(kind):
        w = 2 * np.pi * rng.uniform(1.0, 500.0)
        theta[i] = [2 * rng.uniform(0.001, 0.3) / w, 1 / w**2, rng.normal(0, 2)] if k == 0 else \
            [rng.normal(0, 2), rng.normal(0, 1e-3), rng.normal(0, 1e-3)]
        scale = np.abs(theta[i]) + 1e-6
        P[i] = _spd(rng, 3, 10.0 ** rng.uniform(0, 6)) * np.outer(scale, scale)
        S[i] = _spd(rng, 3, 10.0 ** rng.uniform(0, 3)) / np.outer(scale, scale)
    if how == "indefinite":
        S[0] = -S[0]                                   # a negative sandwich: every variance negative
        P[-1, 0, 1] = P[-1, 1, 0] = 3 * math.sqrt(abs(P[-1, 0, 0] * P[-1, 1, 1])) + 1e-300
    elif how == "nonfinite":
        P[0, 1, 1] = np.nan
        S[-1, 0, 0] = np.inf
        theta[1, 0] = np.nan                           # a non-finite parameter: NaN values, stds and cond
    elif how == "singular":
        P[0] = 0.0                                     # cond 0/0 -> inf, zero covariance
        P[-1, :, 0] = P[-1, 0, :] = 0.0
    elif how == "ill":
        P[0] = _spd(rng, 3, 1e11) * np.outer(np.abs(theta[0]), np.abs(theta[0]))
    elif how == "degenerate":
        theta[0, 1] = -abs(theta[0, 1])                # a2 <= 0: NaN frequency and damping
        theta[-1, 2 if kind[-1] == 0 else 0] = 0.0     # a zero gain: infinite relative std
    return np.asarray(kind, dtype=np.int64), theta, P, S


@pytest.mark.parametrize("kind", [[SECOND, SECOND], [SECOND, SECOND, RIGID2], [RIGID1, SECOND, SECOND, SECOND]])
@pytest.mark.parametrize("how", ["plain", "indefinite", "nonfinite", "singular", "ill", "degenerate"])
def test_compiled_numbers_equal_the_numpy_functions(kind, how):
    rng = np.random.default_rng(abs(hash((tuple(kind), how))) % 2**32)
    for _ in range(25):
        k, theta, P, S = _state(rng, kind, how)
        sig2 = float(rng.uniform(1e-8, 1e-2))
        ref = _reference(k, theta, P, S, sig2)
        cov, info, problems, info_problems, modal, info_rel, cond = _compiled(k, theta, P, S, sig2)
        assert problems == ref["problems"] and info_problems == ref["info_problems"]
        for i, st in enumerate(map(_structure, k)):
            n, nk = st.n_theta, (3 if k[i] == 0 else 1 + k[i])
            p, sa = np.abs(P[i, :nk, :nk]), np.abs(S[i, :nk, :nk])
            with np.errstate(all="ignore"):
                bound = 64 * EPS * sig2 * (p @ sa @ p.T)[:n, :n]
            a, b = cov[i, :n, :n], ref["cov"][i]
            assert np.array_equal(np.isfinite(a), np.isfinite(b))
            fin = np.isfinite(b)
            assert np.all(np.abs(a[fin] - b[fin]) <= bound[fin] + 1e-300)
            _close(info[i, :n, :n], ref["info"][i], 0.0)
            # the stds' variances J C J^T from covariances that differ by up to ``bound``: their terms' magnitudes
            # are those of J (sig2 |P| |S| |P|^T) J^T, not of J |C| J^T (C may cancel far below its terms)
            with np.errstate(all="ignore"):
                terms = sig2 * (p @ sa @ p.T)[:n, :n]
            _close_std(modal[i, 3:], ref["modal"][i][3:], _abs_var(k[i], theta[i], terms))
            if not info_problems[i]:      # the relative std: the same variance bound over |value|
                sd = np.abs(np.asarray(ref["modal"][i][:3]))
                absvar = _abs_var(k[i], theta[i], ref["info"][i])
                with np.errstate(all="ignore"):
                    slack = np.nanmax(np.sqrt(64 * EPS * absvar) / sd)
                if np.isfinite(ref["info_rel"][i]) and np.isfinite(slack):
                    assert abs(info_rel[i] - ref["info_rel"][i]) <= slack + 1e-15 * ref["info_rel"][i]
                else:
                    _close([info_rel[i]], [ref["info_rel"][i]], 1e-12)
        _close(modal[:, :3], np.array(ref["modal"])[:, :3], 1e-15)
        ref_cond = np.array(ref["cond"])
        fin = np.isfinite(ref_cond)
        _close(cond[~fin], ref_cond[~fin], 0.0)
        assert np.all(np.abs(cond[fin] - ref_cond[fin]) <= 1e-13 * ref_cond[fin] ** 2 + 1e-12 * ref_cond[fin])
    if how in ("indefinite", "nonfinite"):
        assert any(problems) or any(info_problems)


def test_the_estimator_publishes_the_compiled_numbers_of_its_state():
    """A running estimator's modal(), iv_condition() and information_relative_std() are those numbers of its state."""
    from frf_cases import CONTROLLER, DELAY, FS, MODES

    from additive_rsrivc_ros.core.estimation.recursive import RecursiveAdditiveSRIVC
    from additive_rsrivc_ros.sim.simulate import simulate_modes, white_noise

    rng = np.random.default_rng(3)
    r = white_noise(int(4 * FS), 0.1, rng)
    sim = simulate_modes(MODES, FS, r=r, controller=CONTROLLER, input_delay=DELAY,
                         noise=white_noise(r.size, 1e-4, rng), rng=rng)
    thetas = [np.array([2 * m.damping_ratio / (2 * np.pi * m.natural_frequency_hz),
                        1 / (2 * np.pi * m.natural_frequency_hz) ** 2, m.gain]) * 1.02 for m in MODES]
    est = RecursiveAdditiveSRIVC([m.structure for m in MODES], thetas, FS, forgetting=0.9995, controller=CONTROLLER,
                                 input_delay=DELAY)
    est.update(sim.r, sim.u, sim.y)
    st = est._s
    ref = _reference(st["kind"], st["theta"], st["P"], st["S"], est.residual_variance)
    _close(est.modal(), np.array(ref["modal"]), 1e-12)
    _close(est.information_relative_std(), ref["info_rel"], 1e-12)
    _close(est.iv_condition(), ref["cond"], 1e-10)
    assert est.covariance_problems() == ref["problems"]
    assert np.all(np.isfinite(est.modal()))
