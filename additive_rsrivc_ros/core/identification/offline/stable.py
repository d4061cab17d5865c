"""Offline continuous-time identification: LSSVF, SRIVC, CLSRIVC, additive SRIVC/CLSRIVC, BCD ([A-SRIVC], [BCD-SRIVC]).

Every estimator returns an :class:`IdentificationResult`; :func:`identify` is the one entry point (the recursive
estimator's start, [RA-SRIVC] Algorithm 2 step 1, and ``rsrivc_identify``). Conventions of ``core/model.py``; the input
is held between samples and delayed ``input_delay`` samples; all filtering is ZOH-exact
(``core/estimation/filters.py``).
Integrators ([A-SRIVC] Remark 6, eqs. 31-32) are part of every method.

* ``additive-clsrivc`` / ``additive-srivc``: [A-SRIVC] eq. 29 with the closed-loop instrument of eq. 20 (``z = S_uo(q)
  r``) / the open-loop one of eq. 10 (``z = u``).
* ``bcd-srivc``: [BCD-SRIVC] Algorithm 2 (SRIVC iterations per block, descent test on ``V_N``).
* ``srivc`` / ``clsrivc``: unfactored ``B/(p^l A)`` ([A-SRIVC] eq. 30, K = 1), split back into the additive form;
  ``lssvf``: one least-squares step with the guess's fixed filter ([UNS-SRIVC] §3); ``*-uns``:
  ``core/identification/offline/unstable.py``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ...controller import DiscreteController
from ...estimation.filters import (
    ClosedLoopUnstableError,
    closed_loop_radius,
    closed_loop_response,
    delay_signal,
    discretize,
    instrument_continuous,
    svf,
    svf_continuous,
)
from ...model import (
    SubmodelStructure,
    frequency_response,
    modal_from_theta,
    modal_std,
    reflect_unstable,
    split_theta,
    total_transfer_function,
)
from .types import METHODS, IdentificationResult, OfflineData, column_norms, equilibrated_solve, finite_or_none


def _check_inputs(u, y, rate_hz: float, structures, thetas0, r, controller, input_delay) -> tuple[OfflineData, list]:
    """Validate the data and the initial model; clear ``ValueError`` messages for bad input."""
    if not (bool(np.isscalar(rate_hz)) and np.isfinite(rate_hz) and rate_hz > 0):  # bool(): no TypeGuard narrowing
        raise ValueError(f"rate_hz must be a positive finite number, got {rate_hz!r}")
    u = np.asarray(u, dtype=float).ravel()
    y = np.asarray(y, dtype=float).ravel()
    if u.size != y.size:
        raise ValueError(f"u and y have different lengths ({u.size} and {y.size})")
    if r is not None:
        r = np.asarray(r, dtype=float).ravel()
        if r.size != y.size:
            raise ValueError(f"r and y have different lengths ({r.size} and {y.size})")
    for name, sig in (("u", u), ("y", y), ("r", r)):
        if sig is not None and not np.all(np.isfinite(sig)):
            raise ValueError(f"{name} contains NaN or inf")
    structures = list(structures)
    if not structures:
        raise ValueError("at least one submodel structure is needed")
    if len(thetas0) != len(structures):
        raise ValueError(f"{len(thetas0)} initial parameter vectors for {len(structures)} submodels")
    thetas = []
    for i, (th, st) in enumerate(zip(thetas0, structures, strict=True)):
        th = np.asarray(th, dtype=float).ravel()
        if th.size != st.n_theta:
            raise ValueError(f"submodel {i + 1}: theta has {th.size} entries, structure needs {st.n_theta}")
        if not np.all(np.isfinite(th)):
            raise ValueError(f"submodel {i + 1}: initial theta contains NaN or inf")
        if st.n > 0 and th[st.n - 1] == 0.0:
            raise ValueError(f"submodel {i + 1}: leading denominator coefficient a_n must be non-zero")
        thetas.append(th)
    if sum(st.is_biproper for st in structures) > 1:
        raise ValueError("at most one submodel may be biproper ([A-SRIVC] §2)")
    n_par = sum(st.n_theta for st in structures)
    delay = int(input_delay)
    if delay < 0:
        raise ValueError(f"input_delay must be >= 0 samples, got {input_delay}")
    need = max(10 * n_par, 4 * n_par + delay + 20)
    if y.size < need:
        raise ValueError(f"too few samples for the model order: {y.size} < {need} ({n_par} parameters)")
    if not np.any(u) and r is None:
        raise ValueError("the input u is identically zero: nothing to identify")
    if (r is None) != (controller is None):
        raise ValueError("closed-loop identification needs both the reference r and the controller")
    data = OfflineData(delay_signal(u, delay), y, r, 1.0 / float(rate_hz), controller, delay)
    return data, thetas


# --------------------------------------------------------------------------------------------------
# the additive IV iteration ([A-SRIVC] eqs. 21-29, Remark 6)


@dataclass
class _Step:
    Z: np.ndarray            # (N, P) instrument [A-SRIVC] eq. 10 / 20 / 31
    Phi: np.ndarray          # (N, P) regressor [A-SRIVC] eq. 24 / 32
    Ups: np.ndarray          # (N, K) filtered residual outputs [A-SRIVC] eq. 22
    xhat: list[np.ndarray]   # submodel outputs G_i u
    eps: np.ndarray          # output error y - sum G_i u


def _blocks(structures: list[SubmodelStructure]) -> list[slice]:
    out, i = [], 0
    for st in structures:
        out.append(slice(i, i + st.n_theta))
        i += st.n_theta
    return out


def _submodel_outputs(data: OfflineData, thetas, structures) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """``p^j/(p^l A_i) u`` (j = 0..m_i) banks and the simulated outputs ``B_i/(p^l A_i) u`` ([A-SRIVC] eq. 23)."""
    banks, xhat = [], []
    for th, st in zip(thetas, structures, strict=True):
        a, b = split_theta(th, st)
        bank = discretize(*svf_continuous(a, st.integrators), data.h).run(data.u, rows=range(st.m + 1))
        banks.append(bank)
        xhat.append(bank @ b)
    return banks, xhat


def _instrument_source(data: OfflineData, thetas, structures, closed_loop: bool) -> np.ndarray:
    """``z = u`` (open loop) or ``z = S_uo(q) r`` of the current model, delayed like ``u`` ([A-SRIVC] eq. 20)."""
    if not closed_loop:
        return data.u
    controller, r = data.loop()
    z, _ = closed_loop_response(thetas, structures, data.h, controller, r, data.delay, check=False)
    return delay_signal(z, data.delay)


def _build(data: OfflineData, thetas, structures, closed_loop: bool, only: int | None = None) -> _Step:
    """Instrument, regressor and filtered outputs of every submodel (or only submodel ``only``).

    The compiled filters write straight into the preallocated (N, P) instrument and regressor matrices, column-major
    so that each filter output is one contiguous column (row-major, every pass wrote across all P columns' cache
    lines: 3x slower at 82k samples).
    """
    idx = list(range(len(structures))) if only is None else [only]
    sts = [structures[i] for i in idx]
    N, P, K = data.n, sum(st.n_theta for st in sts), len(idx)
    Z, Phi, Ups = (np.empty((N, c), order="F") for c in (P, P, K))
    blocks = _blocks(sts)
    xhat: list[np.ndarray] = []
    dss = {}
    for i, (th, st) in enumerate(zip(thetas, structures, strict=True)):
        a, b = split_theta(th, st)
        dss[i] = discretize(*svf_continuous(a, st.integrators), data.h)
        if i in idx:
            sl = blocks[idx.index(i)]
            dst = Phi[:, sl.start + st.n: sl.stop]                   # p^j/(p^l A_i) u, [A-SRIVC] eq. 24 / 32
            dss[i].run(data.u, rows=range(st.m + 1), out=dst)
            xhat.append(dst @ b)
        else:
            xhat.append(dss[i].run(data.u, rows=range(st.m + 1)) @ b)
    total = np.sum(xhat, axis=0)
    z = _instrument_source(data, thetas, structures, closed_loop)
    for k, i in enumerate(idx):
        th, st, sl = thetas[i], structures[i], blocks[k]
        a, _ = split_theta(th, st)
        ytil = data.y - (total - xhat[i])                            # [A-SRIVC] eq. 23
        d_y = dss[i] if st.integrators == 0 else discretize(*svf_continuous(a, 0), data.h)
        d_y.run(ytil, rows=[0], out=Ups[:, k: k + 1])               # [A-SRIVC] eq. 22
        if st.n:
            d_y.run(ytil, rows=range(1, st.n + 1), out=Phi[:, sl.start: sl.start + st.n], sign=-1.0)
            discretize(*instrument_continuous(th, st), data.h).run(   # -p^j B/(p^l A^2) z, [A-SRIVC] eq. 10/20/31
                z, rows=range(1, st.n + 1), out=Z[:, sl.start: sl.start + st.n], sign=-1.0)
        if z is data.u:
            Z[:, sl.start + st.n: sl.stop] = Phi[:, sl.start + st.n: sl.stop]
        else:
            dss[i].run(z, rows=range(st.m + 1), out=Z[:, sl.start + st.n: sl.stop])
    s = data.skip  # the filters start from rest: leave their warm-up out (see warmup_samples)
    step = _Step(Z[s:], Phi[s:], Ups[s:], xhat, (data.y - total)[s:])
    return _without_free_response(step, _free_response_space(data, thetas, structures))


def integrator_free_response(n: int, integrators: int, h: float, start: int = 0) -> np.ndarray:
    """``(n, l)`` orthonormal basis of ``1, t, ..., t^(l-1)``: the free response of ``l`` integrators from the state the
    plant had at the first sample (a rigid body attached in motion: position offset, velocity ramp).
    Submodel outputs simulated from rest never contain it, and it never decays."""
    t = (np.arange(n) + start) * h
    t = t / max(float(t[-1]), h) if n else t
    q, _ = np.linalg.qr(np.vander(t, integrators, increasing=True))
    return q


FREE_RESPONSE_FLOOR = 1e-16  # a free response below this fraction of its start is zero (its basis rows end there)


def _free_response_space(data: OfflineData, thetas, structures) -> tuple[np.ndarray, int] | None:
    """Orthonormal basis of the free responses a model simulated from rest leaves out of the output error, as
    ``(q, L)``: ``q`` spans the first ``L`` rows of the ``N - skip`` samples (zero after them). The integrators'
    polynomials (:func:`integrator_free_response`; a rigid body never decays, ``L`` is every row) and, when the
    record starts in motion (``data.free_response``), the decaying modes of every ``A_i``
    (:func:`free_response_basis`), over the rows until the slowest has decayed to ``FREE_RESPONSE_FLOOR`` (a
    well-damped mode's free response is gone after a fraction of the record: the projection costs only that).
    None when there is none."""
    n = data.n - data.skip
    integrators = max(st.integrators for st in structures)
    rows = n if integrators else 0
    if data.free_response:
        sigma = slowest_decay_rate(thetas, structures)
        if sigma > 0.0:
            rows = max(rows, min(n, int(np.ceil(-np.log(FREE_RESPONSE_FLOOR) / (sigma * data.h))) + 1))
    if rows == 0:
        return None
    cols = [integrator_free_response(n, integrators, data.h, data.skip)] if integrators else []
    if data.free_response:
        cols.append(free_response_basis(thetas, structures, data.h, rows))
    basis = np.hstack([c[:rows] for c in cols])
    if basis.shape[1] == 0:
        return None
    q, rr = np.linalg.qr(basis)
    keep = np.abs(np.diag(rr)) > 1e-9 * max(float(np.max(np.abs(np.diag(rr)))), 1e-300)
    return q[:, keep], rows


def _without_free_response(step: _Step, space: tuple[np.ndarray, int] | None) -> _Step:
    """Project the free response (basis ``q`` of the first ``L`` rows, :func:`_free_response_space`) out of
    instrument, regressor, filtered outputs and output error.

    With the basis ``B`` among both regressors and instruments of every equation ([A-SRIVC] eq. 21 plus the free
    response ``c^T B``, which enters every residual output ``y~_i`` through the submodels' outputs simulated from rest:
    at ``A_i`` the filtered equation's error is ``y~_i`` minus the forced response, i.e. the free responses plus noise),
    the IV estimate of the model parameters equals the IV estimate on the data with ``B`` projected out
    (Frisch-Waugh-Lovell): ``c`` need not be carried. No basis: the step unchanged."""
    if space is None or step.eps.size == 0:
        return step

    def out(x: np.ndarray) -> np.ndarray:
        return _projected_out(x, space)

    return _Step(out(step.Z), out(step.Phi), out(step.Ups), step.xhat, out(step.eps))


def _projected_out(x: np.ndarray, space: tuple[np.ndarray, int]) -> np.ndarray:
    """A copy of ``x`` (vector or columns) with the span of ``q`` removed from its first ``L`` rows
    (``space = (q, L)``, :func:`_free_response_space`)."""
    q, rows = space
    x = x.copy()
    x[:rows] -= q @ (q.T @ x[:rows])
    return x


def _iv_update(step: _Step, structures: list[SubmodelStructure], only: int | None = None) -> tuple[list, float]:
    """[A-SRIVC] eq. 29: ``B^{j+1} = [sum zeta phi^T]^-1 [sum zeta Upsilon^T]``, block diagonal extracted (eq. 27)."""
    M = step.Z.T @ step.Phi
    R = step.Z.T @ step.Ups
    X, cond = equilibrated_solve(M, R, column_norms(step.Z), column_norms(step.Phi))
    sts = structures if only is None else [structures[only]]
    out = [X[sl, i].copy() for i, sl in enumerate(_blocks(sts))]
    return out, cond


def _project(thetas, structures) -> tuple[list[np.ndarray], int]:
    """Reflect right-half-plane roots of every ``A_i`` into the left half plane ([RA-SRIVC] §4.7)."""
    out, count = [], 0
    for th, st in zip(thetas, structures, strict=True):
        if st.n == 0:
            out.append(th)
            continue
        a, b = split_theta(th, st)
        a2, changed = reflect_unstable(a)
        count += int(changed)
        out.append(np.concatenate((a2[1:], b)))
    return out, count


def _time_scale(theta: np.ndarray, st: SubmodelStructure) -> float:
    """``|a_n|^(1/n)`` (1/omega of a second-order mode); 0 for n = 0."""
    return abs(theta[st.n - 1]) ** (1.0 / st.n) if st.n else 0.0


def min_cost_assignment(cost: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows and columns of the minimum-cost one-to-one assignment (``scipy.optimize.linear_sum_assignment``); small
    square problems (a few modes) by enumeration, which spares importing scipy.optimize (half a second)."""
    import itertools

    cost = np.asarray(cost, float)
    n, m = cost.shape
    if n == m and n <= 6:
        rows = np.arange(n)
        best = min(itertools.permutations(range(n)), key=lambda p: (float(cost[rows, list(p)].sum()), p))
        return rows, np.array(best, dtype=int)
    from scipy.optimize import linear_sum_assignment

    return linear_sum_assignment(cost)


def match_order(thetas: list[np.ndarray], reference: list[np.ndarray], structures) -> tuple[list[np.ndarray], bool]:
    """Permute submodels of identical structure so that they follow the reference's (e.g. the initial
    guesses') order by time scale. Any permutation is the same additive model ([A-SRIVC] §2: the decomposition is
    unique up to the labels), so this only restores the user's labelling after an iteration swapped two."""
    out = list(thetas)
    swapped = False
    for st in set(structures):
        idx = [i for i, s2 in enumerate(structures) if s2 == st]
        if len(idx) < 2 or st.n == 0:
            continue
        te = np.array([_time_scale(thetas[i], st) for i in idx])
        tr = np.array([_time_scale(reference[i], st) for i in idx])
        if np.any(te <= 0) or np.any(tr <= 0):
            continue
        cost = np.abs(np.log(te)[:, None] - np.log(tr)[None, :])
        rows, cols = min_cost_assignment(cost)
        for r_, c_ in zip(rows, cols, strict=True):
            if r_ != c_:
                swapped = True
            out[idx[c_]] = thetas[idx[r_]]
    return out, swapped


def _finite(thetas) -> bool:
    return all(np.all(np.isfinite(t)) for t in thetas)


def relative_change(new: list[np.ndarray], old: list[np.ndarray], scale: np.ndarray) -> float:
    """``||beta_new - beta_old|| / ||beta_old||`` with each parameter scaled by its initial magnitude."""
    bn, bo = np.concatenate(new) / scale, np.concatenate(old) / scale
    return float(np.linalg.norm(bn - bo) / max(float(np.linalg.norm(bo)), 1e-300))


def _cl_ok(data: OfflineData, thetas, structures) -> bool:
    try:
        return closed_loop_radius(thetas, structures, data.h, data.loop()[0], data.delay) < 1.0
    except (ValueError, np.linalg.LinAlgError):
        return False


def _safeguard(data, thetas_new, thetas_old, structures, closed_loop: bool, projection: bool):
    """Projection ([RA-SRIVC] §4.7) and, in closed loop, step halving until the controller stabilizes the iterate.

    Returns ``(thetas, projections, note)``; ``thetas`` is None when no admissible step was found.
    """
    proj = 0
    if projection:
        thetas_new, proj = _project(thetas_new, structures)
    if not closed_loop or _cl_ok(data, thetas_new, structures):
        return thetas_new, proj, ""
    for k in range(1, 11):
        w = 0.5 ** k
        trial = [o + w * (n - o) for n, o in zip(thetas_new, thetas_old, strict=True)]
        if projection:
            trial, p2 = _project(trial, structures)
            proj += p2
        if _cl_ok(data, trial, structures):
            return trial, proj, f"step halved {k} time(s) to keep the closed loop stable"
    return None, proj, "no iterate stabilized by the controller near the previous one"


def _finalize(method: str, data: OfflineData, structures, thetas, closed_loop: bool, iterations: int, converged: bool,
              cond: float, projections: int, message: str, thetas_cov=None) -> IdentificationResult:
    """Covariance ([A-SRIVC] Theorem 1, sandwich form), residual variance, cost, modal values and their stds."""
    step = _build(data, thetas, structures, closed_loop)
    N, P = step.Z.shape
    rss = float(step.eps @ step.eps)
    sigma2 = rss / max(N - P, 1)
    M = step.Z.T @ step.Phi
    try:
        Minv = np.linalg.inv(M)
        G = step.Z.T @ step.Z
        cov = sigma2 * Minv @ G @ Minv.T
        cov = 0.5 * (cov + cov.T)
        dz = 1.0 / column_norms(step.Z)
        dp = 1.0 / column_norms(step.Phi)
        cond_final = float(np.linalg.cond(dz[:, None] * M * dp[None, :]))
    except np.linalg.LinAlgError:
        Minv = np.full((P, P), np.nan)
        cov = np.full((P, P), np.nan)
        cond_final = np.inf
        message = (message + "; " if message else "") + "IV normal matrix singular at the estimate"
        converged = False
    blocks = _blocks(structures)
    p_blocks = []
    for sl in blocks:
        try:
            p_blocks.append(np.linalg.inv(M[sl, sl]))
        except np.linalg.LinAlgError:
            p_blocks.append(np.full((sl.stop - sl.start,) * 2, np.nan))
    covs = [cov[sl, sl].copy() for sl in blocks]
    modal = np.array([modal_from_theta(t, s) for t, s in zip(thetas, structures, strict=True)])
    mstd = np.array([modal_std(t, c, s) for t, c, s in zip(thetas, covs, structures, strict=True)])
    return IdentificationResult(
        method=method, structures=list(structures), thetas=[np.asarray(t, float) for t in thetas],
        covariances=covs, covariance=cov, P=Minv, p_blocks=p_blocks, residual_variance=sigma2,
        iterations=iterations, converged=converged, cond=cond_final if np.isfinite(cond_final) else cond,
        cost=rss / N, modal=modal, modal_std=mstd, projections=projections, message=message, n_samples=N)


SETTLE_ITERATIONS = 3  # additive_iv(settle_tol=...): iterations without a gain in output error that end a fit


def additive_iv(data: OfflineData, structures, thetas0, *, closed_loop: bool, method: str, max_iterations: int = 50,
                tol: float = 1e-7, projection: bool = True, settle_tol: float | None = None,
                settle_floor: float = 0.0) -> IdentificationResult:
    """Additive SRIVC / CLSRIVC: iterate [A-SRIVC] eq. 29 (K = 1: SRIVC/CLSRIVC of [A-SRIVC] eq. 30).

    Open loop ``zeta`` = [A-SRIVC] eq. 10 (gradient of the output error), closed loop [A-SRIVC] eq. 20 with
    ``z = S_uo(q) r``; integrators per [A-SRIVC] Remark 6 (eqs. 31-32). Stops when the scaled relative change
    of beta is below ``tol``; a failure (singular normal matrix, no stabilized iterate, iteration limit)
    returns the last admissible iterate with ``converged=False`` and a message.

    ``settle_tol`` (the order scan's short fits, :mod:`..modefind`): also stop once the output error of the
    iterates ([A-SRIVC] eq. 23 summed, the cost the scan judges a model by) has not fallen by more than ``settle_tol``
    of its best for :data:`SETTLE_ITERATIONS` iterations; the best iterate is returned, not converged, with
    ``extra["settled"]``. A submodel the data do not inform (one mode too many) moves its parameters for dozens of
    iterations without changing the output error; the parameter test alone keeps iterating it. Only an output error
    at or above ``settle_floor`` settles: a fit below it (the order scan: better than the model it must beat) may be
    on its way to a much better optimum and is iterated as usual.
    """
    thetas = [np.asarray(t, float).copy() for t in thetas0]
    scale = np.abs(np.concatenate(thetas))
    scale = np.where(scale > 0, scale, 1.0)
    projections, cond, message, converged, it = 0, np.nan, "", False, 0
    change, at_limit = np.inf, np.inf
    best_cost, best_thetas, flat, settled = np.inf, thetas, 0, False
    if projection:   # the filters are built from the initial guess too ([RA-SRIVC] §4.7)
        thetas, projections = _project(thetas, structures)
    for it in range(1, max_iterations + 1):
        try:
            step = _build(data, thetas, structures, closed_loop)
            if settle_tol is not None:
                cost = float(step.eps @ step.eps) / max(step.eps.size, 1)
                flat = 0 if cost < (1.0 - settle_tol) * best_cost else flat + 1
                if cost < best_cost:
                    best_cost, best_thetas = cost, thetas
                if flat >= SETTLE_ITERATIONS and best_cost >= settle_floor:
                    thetas, settled, it = best_thetas, True, it - 1
                    message = (f"output error settled (within {settle_tol:.0e} of its best for {SETTLE_ITERATIONS} "
                               f"iterations; last relative parameter change {change:.3g}): judged where it stands")
                    break
            new, cond = _iv_update(step, structures)
        except np.linalg.LinAlgError as exc:
            message = f"iteration {it}: {exc}"
            it -= 1
            break
        if not _finite(new):
            message = f"iteration {it}: non-finite estimate"
            it -= 1
            break
        new, p, note = _safeguard(data, new, thetas, structures, closed_loop, projection)
        projections += p
        if new is None:
            message = f"iteration {it}: {note}"
            it -= 1
            break
        change = relative_change(new, thetas, scale)
        thetas = new
        if change < tol:
            converged = True
            break
    else:
        message = f"no convergence within {max_iterations} iterations (last relative change {change:.3g})"
        at_limit = change
    if converged and not message:
        message = "converged"
    thetas, swapped = match_order(thetas, thetas0, structures)
    if swapped:
        message += "; submodels re-labelled to follow the initial guesses' order"
    res = _finalize(method, data, structures, thetas, closed_loop, it, converged, cond, projections, message)
    res.extra["change_at_limit"] = float(at_limit)   # the last step's relative change when out of iterations
    if settled:
        res.extra["settled"] = True
    return res



def fit_usable(res: IdentificationResult) -> bool:
    """A fit to keep and test: finite, and converged, or its output error settled (``settle_tol``), or out of
    iterations while its last step moved the parameters by less than :data:`NEARLY_CONVERGED`."""
    return _finite(res.thetas) and (res.converged or bool(res.extra.get("settled"))
                                    or res.extra.get("change_at_limit", np.inf) < NEARLY_CONVERGED)


def _cost(data: OfflineData, xhat_sum: np.ndarray, thetas=None, structures=None) -> float:
    e = (data.y - xhat_sum)[data.skip:]
    space = _free_response_space(data, thetas, structures) if data.free_response and thetas is not None else None
    if space is not None:
        e = _projected_out(e, space)
    return float(e @ e) / e.size


def in_motion_skip(data: OfflineData) -> int:
    """Samples left out at the start of a record in motion: the first ``input_delay`` outputs still answer inputs
    sent before the record (in the delay line), which no initial condition of the modes reproduces."""
    return min(int(data.delay), max(data.n - 1, 0))


def output_error_variance(u, y, rate_hz: float, structures, thetas, *, input_delay: int = 0) -> float:
    """Mean squared output error ([BCD-SRIVC] eq. 8) of the model ``thetas`` on a record that starts in motion: the
    submodels simulated from ``u`` ([A-SRIVC] eq. 23), the free response of their modes projected out
    (:func:`_free_response_space`). Judges a model on data it was not fitted to (e.g. the later part of a window)."""
    data, thetas = _check_inputs(u, y, rate_hz, structures, thetas, None, None, input_delay)
    data.free_response, data.skip = True, in_motion_skip(data)
    _, xhat = _submodel_outputs(data, thetas, list(structures))
    return _cost(data, np.sum(xhat, axis=0), thetas, list(structures))


def bcd_srivc(data: OfflineData, structures, thetas0, *, max_iterations: int = 50, tol: float = 1e-7,
              inner_iterations: int = 20, projection: bool = True, closed_loop: bool = False) -> IdentificationResult:
    """Block-coordinate descent SRIVC ([BCD-SRIVC] Algorithm 2): per block, SRIVC iterations ([BCD-SRIVC] eq. 12) on the
    residual output until ``V_N`` ([BCD-SRIVC] eq. 8) decreases; stop on the relative change of x (line 15)."""
    thetas = [np.asarray(t, float).copy() for t in thetas0]
    K = len(structures)
    scale = np.abs(np.concatenate(thetas))
    scale = np.where(scale > 0, scale, 1.0)
    projections, cond, converged, message, it = 0, np.nan, False, "", 0
    if projection:
        thetas, projections = _project(thetas, structures)
    _, xhat = _submodel_outputs(data, thetas, structures)
    for sweep in range(1, max_iterations + 1):
        it = sweep
        old = [t.copy() for t in thetas]
        for i in range(K):
            others = np.sum(xhat, axis=0) - xhat[i]
            v_start = _cost(data, others + xhat[i], thetas, structures)
            trial = [t.copy() for t in thetas]
            for _s in range(inner_iterations):
                try:
                    step = _build(data, trial, structures, closed_loop, only=i)
                    new_i, cond = _iv_update(step, structures, only=i)
                except np.linalg.LinAlgError as exc:
                    message = f"block {i + 1}: {exc}"
                    break
                if not np.all(np.isfinite(new_i[0])):
                    break
                cand = [t.copy() for t in trial]
                cand[i] = new_i[0]
                cand, p, _ = _safeguard(data, cand, trial, structures, closed_loop, projection)
                projections += p
                if cand is None:
                    break
                trial = cand
                _, xi = _submodel_outputs(data, [trial[i]], [structures[i]])
                if _cost(data, others + xi[0], trial, structures) < v_start:       # [BCD-SRIVC] Algorithm 2 line 8
                    thetas = trial
                    xhat[i] = xi[0]
                    break
        change = relative_change(thetas, old, scale)
        if change < tol:
            converged = True
            break
    else:
        message = f"no convergence within {max_iterations} sweeps (last relative change {change:.3g})"
    if converged:
        message = "converged"
    thetas, swapped = match_order(thetas, thetas0, structures)
    if swapped:
        message += "; submodels re-labelled to follow the initial guesses' order"
    return _finalize("bcd-srivc", data, structures, thetas, closed_loop, it, converged, cond, projections, message)


# --------------------------------------------------------------------------------------------------
# unfactored models (K = 1) and the partial-fraction split back into submodels


def unfactored_structure(structures: list[SubmodelStructure]) -> SubmodelStructure:
    """Smallest ``B/(p^l A)`` that contains the additive model ([BCD-SRIVC] Proposition 1)."""
    n = sum(st.n for st in structures)
    l_tot = sum(st.integrators for st in structures)
    m = max(st.m + (n + l_tot) - (st.n + st.integrators) for st in structures)
    return SubmodelStructure(n=n, m=m, integrators=l_tot)


def to_unfactored(thetas, structures) -> tuple[np.ndarray, SubmodelStructure]:
    """The additive model as one ``theta`` of :func:`unfactored_structure` ([A-SRIVC] eq. 1)."""
    su = unfactored_structure(structures)
    num, den = total_transfer_function(thetas, structures)
    den = den[su.integrators:]
    num = np.concatenate((num, np.zeros(max(0, su.m + 1 - num.size))))[: su.m + 1]
    return np.concatenate((den[1: su.n + 1] / den[0], num / den[0])), su


def split_additive(theta_u: np.ndarray, su: SubmodelStructure, structures: list[SubmodelStructure],
                   thetas_ref: list[np.ndarray]) -> list[np.ndarray]:
    """Partial-fraction split of an unfactored ``B/(p^l A)`` into the additive structures ([BCD-SRIVC] §4.1).

    The roots of ``A`` are assigned to the submodels by matching the poles of ``thetas_ref`` (Hungarian
    assignment); the numerators are the least-squares fit of the frequency response with those
    denominators (exact when the unfactored model is additive; extra numerator terms are dropped).
    """
    a, b = split_theta(theta_u, su)
    roots = np.roots(a[::-1]) if su.n > 0 else np.zeros(0)
    ref_roots: list[complex] = []
    owner: list[int] = []
    for i, (th, st) in enumerate(zip(thetas_ref, structures, strict=True)):
        if st.n > 0:
            ai, _ = split_theta(th, st)
            rr = np.roots(ai[::-1])
            ref_roots.extend(rr)
            owner.extend([i] * rr.size)
    den_i = []
    if roots.size:
        cost = np.abs(roots[:, None] - np.asarray(ref_roots)[None, :]) / np.maximum(np.abs(ref_roots), 1e-12)[None, :]
        ri, ci = min_cost_assignment(cost)
        groups: list[list[complex]] = [[] for _ in structures]
        for r_idx, c_idx in zip(ri, ci, strict=True):
            groups[owner[c_idx]].append(roots[r_idx])
    else:
        groups = [[] for _ in structures]
    for i in range(len(structures)):
        poly = np.array([1.0 + 0j])
        for rt in groups[i]:
            poly = np.polynomial.polynomial.polymul(poly, np.array([1.0, -1.0 / rt]))
        if np.max(np.abs(poly.imag)) > 1e-6 * np.max(np.abs(poly)):
            raise ValueError("partial-fraction split failed: complex roots were not paired within a submodel")
        den_i.append(poly.real)
    # numerators: least squares on the frequency response over a band covering every pole
    mags = np.abs(np.concatenate([roots, np.asarray(ref_roots)])) if roots.size else np.array([1.0])
    wlo, whi = max(mags.min() / 20, 1e-6), mags.max() * 20
    w = np.logspace(np.log10(wlo), np.log10(whi), 400)
    s = 1j * w
    g = np.polyval(b[::-1], s) / (s**su.integrators * np.polyval(a[::-1], s))
    cols = []
    for st, dn in zip(structures, den_i, strict=True):
        base = 1.0 / (s**st.integrators * np.polyval(dn[::-1], s))
        cols.extend([base * s**j for j in range(st.m + 1)])
    Amat = np.array(cols).T
    wt = 1.0 / np.maximum(np.abs(g), 1e-300)
    Ar = np.vstack(((Amat * wt[:, None]).real, (Amat * wt[:, None]).imag))
    gr = np.concatenate(((g * wt).real, (g * wt).imag))
    cn = column_norms(Ar)
    coef = np.linalg.lstsq(Ar / cn, gr, rcond=None)[0] / cn
    out, k = [], 0
    for st, dn in zip(structures, den_i, strict=True):
        out.append(np.concatenate((dn[1: st.n + 1], coef[k: k + st.m + 1])))
        k += st.m + 1
    return out


def unfactored_iv(data: OfflineData, structures, thetas0, *, closed_loop: bool, method: str, max_iterations: int = 50,
                  tol: float = 1e-7, projection: bool = True) -> IdentificationResult:
    """Unfactored SRIVC / CLSRIVC ([A-SRIVC] eq. 30, Remark 5) on ``B/(p^l A)``, then split into the submodels.

    The additive covariance follows from the unfactored one by the delta method through the split.
    """
    th_u0, su = to_unfactored(thetas0, structures)
    res = additive_iv(data, [su], [th_u0], closed_loop=closed_loop, method=method, max_iterations=max_iterations,
                      tol=tol, projection=projection)
    if len(structures) == 1:
        return res
    th_u = res.thetas[0]
    try:
        thetas = split_additive(th_u, su, structures, thetas0)
    except (ValueError, np.linalg.LinAlgError) as exc:
        res.message += f"; split into submodels failed ({exc})"
        res.converged = False
        return res
    # delta method through the split (central differences)
    base = np.concatenate(thetas)
    J = np.zeros((base.size, th_u.size))
    for j in range(th_u.size):
        dh = 1e-6 * max(abs(th_u[j]), 1e-12)
        tp, tm = th_u.copy(), th_u.copy()
        tp[j] += dh
        tm[j] -= dh
        J[:, j] = (np.concatenate(split_additive(tp, su, structures, thetas)) -
                   np.concatenate(split_additive(tm, su, structures, thetas))) / (2 * dh)
    cov = J @ res.covariance @ J.T
    P = J @ res.P @ J.T
    blocks = _blocks(structures)
    covs = [cov[sl, sl] for sl in blocks]
    modal = np.array([modal_from_theta(t, s) for t, s in zip(thetas, structures, strict=True)])
    mstd = np.array([modal_std(t, c, s) for t, c, s in zip(thetas, covs, structures, strict=True)])
    # output error of the split model (dropped numerator terms show up here)
    _, xhat = _submodel_outputs(data, thetas, structures)
    eps = data.y - np.sum(xhat, axis=0)
    return IdentificationResult(
        method=method, structures=list(structures), thetas=thetas, covariances=covs, covariance=cov, P=P,
        p_blocks=[P[sl, sl] for sl in blocks], residual_variance=res.residual_variance,
        iterations=res.iterations, converged=res.converged, cond=res.cond, cost=float(eps @ eps) / data.n,
        modal=modal, modal_std=mstd, projections=res.projections, message=res.message, n_samples=data.n,
        extra={"unfactored_theta": th_u, "unfactored_structure": su, "unfactored_covariance": res.covariance})


def lssvf(data: OfflineData, structures, thetas0, *, method: str = "lssvf") -> IdentificationResult:
    """Least-squares state-variable filter ([UNS-SRIVC] §3): one LS step with the fixed filter ``1/A_f`` of the guess.

    Uses the unfactored model with ``A_f`` the total denominator of the initial guess, then the additive
    split. (An unstable ``A_f`` needs the all-pass extension: ``lssvf-uns``, [UNS-SRIVC] Remark 2.)
    """
    th_u0, su = to_unfactored(thetas0, structures)
    a_f, _ = split_theta(th_u0, su)
    fy = svf(a_f, data.y, data.h, 0)
    fu = svf(a_f, data.u, data.h, su.integrators)
    Phi = np.hstack((-fy[:, 1: su.n + 1], fu[:, : su.m + 1]))
    pn = column_norms(Phi)
    X, cond = equilibrated_solve(Phi.T @ Phi, (Phi.T @ fy[:, 0])[:, None], pn, pn)
    th_u = X[:, 0]
    thetas = [th_u] if len(structures) == 1 else split_additive(th_u, su, structures, thetas0)
    res = _finalize(method, data, structures, thetas, False, 1, True, cond, 0, "least squares (one step)")
    res.extra["unfactored_theta"] = th_u
    return res


# --------------------------------------------------------------------------------------------------
# entry point


WARMUP_DECAY_TIMES = 5.0  # default warm-up: this many decay times of the slowest mode of the initial model


@dataclass
class TransientTest:
    """Outcome of :func:`initial_transient_test`: ``statistic`` (F ratio) against ``threshold``."""

    statistic: float
    threshold: float
    window: int
    detected: bool

    def to_dict(self) -> dict[str, Any]:
        return {"statistic": finite_or_none(self.statistic), "threshold": finite_or_none(self.threshold),
                "window": int(self.window), "detected": bool(self.detected)}


TRANSIENT_FALSE_ALARM = 1e-3


def free_response_basis(thetas, structures, h: float, window: int) -> np.ndarray:
    """``(window, d)`` free responses ``e^(sigma t) cos(omega t)``, ``e^(sigma t) sin(omega t)`` (``e^(sigma t)`` for a
    real pole) of every asymptotically stable pole of the ``A_i``: the shapes an initial condition of the plant
    leaves in the output error ``y - sum_i G_i u`` of a model simulated from rest. Integrators are left out."""
    t = np.arange(window) * h
    cols = []
    for th, st in zip(thetas, structures, strict=True):
        if st.n == 0:
            continue
        a, _ = split_theta(th, st)
        for pole in np.roots(a[::-1]):
            if pole.real >= 0 or pole.imag < 0:
                continue
            env = np.exp(pole.real * t)
            cols.append(env * np.cos(pole.imag * t))
            if pole.imag > 0:
                cols.append(env * np.sin(pole.imag * t))
    return np.array(cols).T if cols else np.zeros((window, 0))


def initial_transient_test(eps: np.ndarray, thetas, structures, h: float, window: int,
                           false_alarm: float = TRANSIENT_FALSE_ALARM) -> TransientTest:
    """Does the output error ``eps`` of the fitted model start with the plant's free response?

    A record that starts with the plant in motion leaves the plant's initial-condition response in
    ``y - sum_i G_i u`` (both simulated from rest), a combination of the model's own decaying modes
    (:func:`free_response_basis`). Its energy over the first ``window`` samples, ``Q_0 = |P_B eps_0|^2``,
    is compared with the same projection of later windows of the same record, which measures the noise's own
    level at those modes' frequencies (coloured noise included): ``F = Q_0 / mean(Q_j)`` against the
    ``1 - false_alarm`` quantile of ``F(d, d n_indep)``, with ``n_indep`` the non-overlapping later windows.
    """
    n = eps.size
    basis = free_response_basis(thetas, structures, h, window)
    d = basis.shape[1]
    if d == 0 or window < 2 * d or n < 2 * window or not np.all(np.isfinite(eps)):
        return TransientTest(np.nan, np.nan, window, False)
    q, _ = np.linalg.qr(basis)

    def energy(seg: np.ndarray) -> float:
        c = q.T @ seg
        return float(c @ c)

    n_indep = (n - window) // window
    starts = np.linspace(window, n - window, min(16, max(n_indep, 1) * 4)).astype(int)
    null = np.mean([energy(eps[s0: s0 + window]) for s0 in starts])
    from scipy.special import fdtri  # lazy: the node and the tools start without scipy.special

    threshold = float(fdtri(float(d), float(d * n_indep), 1.0 - false_alarm))   # quantile of F(d, d n_indep)
    stat = energy(eps[:window]) / null if null > 0 else np.inf
    return TransientTest(float(stat), threshold, window, bool(stat > threshold))


def slowest_decay_rate(thetas, structures) -> float:
    """``min |Re p|`` [1/s] over the asymptotically stable poles ``p`` of every ``A_i`` (0 when there is none;
    integrators never decay and do not count): one over the longest decay time of the model's free response."""
    rates = []
    for th, st in zip(thetas, structures, strict=True):
        if st.n == 0:
            continue
        a, _ = split_theta(th, st)
        re = -np.roots(a[::-1]).real
        rates += [float(v) for v in re[re > 0]]
    return min(rates, default=0.0)


def warmup_samples(thetas, structures, rate_hz: float, n: int, warmup_s: float | None = None) -> int:
    """Samples at the start of the record left out of the IV normal equations and the cost.

    The prefilters, the simulated submodel outputs and the closed-loop instrument start from rest. When the
    recording starts with the plant in motion (the usual case for a monitor that attaches to a running
    machine), the regression equations ([A-SRIVC] eq. 21) hold only up to the initial-condition response until
    those transients have decayed; for a lightly damped mode driven near resonance that transient carries as
    much energy as all the noise of a long record and biases b0 and zeta together (the resonance peak
    b0/(2 zeta) stays right). ``warmup_s`` given: that many seconds. ``None``: ``WARMUP_DECAY_TIMES`` decay
    times ``1/|Re pole|`` of the slowest asymptotically stable submodel of ``thetas``. Integrators never decay
    and do not count. At most a quarter of the record either way.
    """
    if warmup_s is None:
        sigma = slowest_decay_rate(thetas, structures)
        warmup_s = WARMUP_DECAY_TIMES * (1.0 / sigma) if sigma > 0.0 else 0.0
    if not (np.isfinite(warmup_s) and warmup_s >= 0):
        raise ValueError(f"warmup_s must be >= 0, got {warmup_s!r}")
    return int(min(round(warmup_s * rate_hz), n // 4))


NEARLY_CONVERGED = 1e-2  # relative parameter change of a last iterate that is tested, not refitted from the guess
FREE_RESPONSE_REFIT = True  # a record in motion is refitted with the free response projected out (else: warm-up)


def _refit_if_started_in_motion(res: IdentificationResult, data: OfflineData, structures, thetas0,
                                refit) -> IdentificationResult:
    """A record in motion: keep the fit over every sample unless its output error starts with the plant's free
    response (:func:`initial_transient_test`); then refit on every sample with the free response of the model's
    modes projected out (``data.free_response``, :func:`_free_response_space`: the initial conditions estimated
    with the parameters), from the first fit and, failing that, from the initial guess; if neither converges, with
    the filters' warm-up left out instead (at most a quarter of the record, which five decay times of a lightly
    damped mode can exceed: a 60 s window of the paper's example was then biased by 52 standard deviations). From
    rest the start-up transient is information (with steady sine excitation often most of it), so nothing is lost
    there. A first fit that failed gets one refit from the initial guess with the free response projected out; one
    that only ran out of iterations while its last step moved the parameters by less than ``NEARLY_CONVERGED`` is
    a model like any other and is tested (refitting it from the guess doubled the cost of the order scan's short
    fits)."""
    ok = fit_usable(res)
    base = res.thetas if ok else thetas0
    rate = 1.0 / data.h
    skip = warmup_samples(base, structures, rate, data.n)
    if skip == 0:
        return res
    test = None
    if ok:
        _, xhat = _submodel_outputs(data, res.thetas, structures)
        test = initial_transient_test(data.y - np.sum(xhat, axis=0), res.thetas, structures, data.h, skip)
        res.extra["initial_transient"] = test.to_dict()
        if not test.detected:
            return res
    # the model's free response estimated with it (initial conditions, Frisch-Waugh): every sample is kept
    why = (f"output error starts with the plant's free response (F = {test.statistic:.3g} > {test.threshold:.3g})"
           if test is not None else "the fit over every sample failed")
    # from the first fit and, if that fails (a transient can pull the first fit into another optimum, e.g. a
    # lightly damped mode split in two while the other mode was lost), from the initial guess
    data.free_response, data.skip = True, in_motion_skip(data)
    for start in ([base, thetas0] if base is not thetas0 else [thetas0]) if FREE_RESPONSE_REFIT else []:
        new = refit([np.asarray(t, float).copy() for t in start])
        usable = fit_usable(new)
        if usable or test is None:   # a first fit that failed gets one refit, as it had with the warm-up alone
            new.message += f"; {why}: refitted with the free response of the model's modes projected out"
            if test is not None:
                new.extra["initial_transient"] = test.to_dict()
            new.extra["free_response"] = True
            return new
    data.free_response = False
    # the fit over a transient is biased towards more damping (a shorter decay): take the longer of its warm-up
    # and the initial guess's, and lengthen it while the refitted model decays more slowly
    skip = max(skip, warmup_samples(thetas0, structures, rate, data.n))
    for _ in range(3):
        data.skip = skip
        new = refit([np.asarray(t, float).copy() for t in base])
        if not (new.converged and _finite(new.thetas)):
            break
        longer = warmup_samples(new.thetas, structures, rate, data.n)
        if longer <= 1.1 * skip:
            break
        skip, base = longer, new.thetas
    new.message += f"; {why}: the first {skip * data.h:.4g} s only warm up the filters"
    if test is not None:
        new.extra["initial_transient"] = test.to_dict()
    new.extra["warmup_samples"] = skip
    return new


def identify(u, y, rate_hz: float, structures, thetas0, *, r=None, controller: DiscreteController | None = None,
             input_delay: int = 0, method: str = "auto", max_iterations: int = 50, tol: float = 1e-7,
             projection: bool = True, warmup_s: float | None = None, in_motion: bool = False,
             settle_tol: float | None = None, settle_floor: float = 0.0) -> IdentificationResult:
    """Identify the additive continuous-time model ``sum_i B_i/(p^l_i A_i)`` from sampled data.

    ``u`` is the plant input (held between samples, reaching the plant ``input_delay`` samples late),
    ``y`` the measured output, ``r`` the reference (closed loop, with the discrete ``controller``
    ``u = C_d (r - y)``). ``method``: see :data:`METHODS`; ``auto`` is ``additive-clsrivc`` when ``r`` and
    ``controller`` are given, else ``additive-srivc``. Bad input raises ``ValueError``; non-convergence is
    reported in the result (``converged=False``, ``message``). The first ``warmup_s`` seconds only warm up
    the filters (:func:`warmup_samples`; 0 uses every sample). Default ``None``: every sample, unless the
    fit's output error starts with the plant's free response (:func:`initial_transient_test`, the record starts
    in motion); then it is refitted with that free response projected out (:func:`_refit_if_started_in_motion`).
    ``in_motion``: the record starts in motion, so that projection starts at the first fit (a fit biased by the
    transient can pass the test). The unstable-plant methods (``*-uns``, ``*-monic``) use every sample. ``settle_tol``,
    ``settle_floor``: the additive methods also stop when the output error has settled above the floor
    (:func:`additive_iv`; for quick fits that are judged by their output error, e.g. the order scan).
    """
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; choose one of {', '.join(METHODS)}")
    if not (isinstance(max_iterations, int | np.integer) and max_iterations >= 1):
        raise ValueError(f"max_iterations must be a positive integer, got {max_iterations!r}")
    if not (np.isfinite(tol) and tol > 0):
        raise ValueError(f"tol must be positive, got {tol!r}")
    data, thetas = _check_inputs(u, y, rate_hz, structures, thetas0, r, controller, input_delay)
    structures = list(structures)
    auto_warmup = warmup_s is None
    data.skip = 0 if auto_warmup else warmup_samples(thetas, structures, rate_hz, data.n, warmup_s)
    if method == "auto":
        method = "additive-clsrivc" if data.closed_loop else "additive-srivc"
    needs_cl = method in ("additive-clsrivc", "clsrivc", "clsrivc-uns", "clsrivc-uns-monic")
    if needs_cl and not data.closed_loop:
        raise ValueError(f"method {method} needs the reference r and the controller (closed-loop data)")
    if method.endswith("-uns") or method.endswith("-monic"):
        from .unstable import identify_unstable
        return identify_unstable(data, structures, thetas, method=method, max_iterations=max_iterations, tol=tol)
    if needs_cl:
        if method == "clsrivc":
            th_u, su = to_unfactored(thetas, structures)
            if not _cl_ok(data, [th_u], [su]):
                raise ClosedLoopUnstableError(_unstable_msg(data, [th_u], [su]))
        elif not _cl_ok(data, thetas, structures):
            raise ClosedLoopUnstableError(_unstable_msg(data, thetas, structures))
    def run(start: list[np.ndarray]) -> IdentificationResult:
        if method in ("additive-clsrivc", "additive-srivc"):
            return additive_iv(data, structures, start, closed_loop=needs_cl, method=method, settle_tol=settle_tol,
                               settle_floor=settle_floor, max_iterations=max_iterations, tol=tol,
                               projection=projection)
        if method in ("srivc", "clsrivc"):
            return unfactored_iv(data, structures, start, closed_loop=needs_cl, method=method,
                                 max_iterations=max_iterations, tol=tol, projection=projection)
        if method == "bcd-srivc":
            return bcd_srivc(data, structures, start, max_iterations=max_iterations, tol=tol, projection=projection)
        return lssvf(data, structures, start)

    if in_motion and auto_warmup:
        data.free_response, data.skip = True, in_motion_skip(data)
        res = run(thetas)
        if fit_usable(res):
            res.message += "; the record starts in motion: the free response of the model's modes projected out"
            res.extra["free_response"] = True
            return res
        data.free_response, data.skip = False, 0     # the projected fit failed: the test and its fallbacks below
    res = run(thetas)
    if auto_warmup:
        res = _refit_if_started_in_motion(res, data, structures, thetas, run)
    return res


def _unstable_msg(data: OfflineData, thetas, structures) -> str:
    try:
        rho = closed_loop_radius(thetas, structures, data.h, data.loop()[0], data.delay)
        return (f"the controller does not stabilize the initial model (closed-loop spectral radius {rho:.4g} >= 1); "
                "check the controller, the input delay and the initial guess")
    except ValueError as exc:
        return f"the closed loop of the initial model cannot be formed: {exc}"


def model_frf(result: IdentificationResult, freqs_hz: np.ndarray, input_delay_s: float = 0.0) -> np.ndarray:
    """Frequency response of an identified model (convenience wrapper of ``model.frequency_response``)."""
    return frequency_response(result.thetas, result.structures, freqs_hz, input_delay_s)
