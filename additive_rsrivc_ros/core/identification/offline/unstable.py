"""Unstable plants and integral action: LSSVF-uns, SRIVC-uns, CLSRIVC-uns ([UNS-SRIVC] §4-§6), K = 1.

``1/A(p)`` is unstable for an unstable model, so every filtered signal is multiplied by the discrete all-pass
``A_da(q)/Abar_da(q)`` (eqs. 15-16) whose zeros are the unstable poles of the ZOH equivalent ``A_d(q)`` (eq. 12),
realized as the stable filter ``N_j(q) / (A_ds(q) Abar_da(q))``. Both all-pass polynomials are monic in ``q^-1``, which
keeps (17) a proper predictor (Lemma 4.3); the residual variance is divided by ``prod |lambda|^2``.

* ``lssvf-uns``: one LS step of eq. 24 with the fixed filter of the guess (Remark 2).
* ``srivc-uns``: eq. 25 with the instrument of eq. 26 (the stable predictor's gradient, by central differences, §7.1).
* ``clsrivc-uns``: eq. 25 with the instrument of eq. 29, ``AP [-p^j/A T_o r, p^j/(p^l A) S_uo r]``.
* integral action (§6): ``integrators > 0`` forces the poles at 0 (solution 2); ``*-uns-monic`` uses the monic ``A = a_0
  + .. + p^n`` so ``a_0`` can go to zero (solution 1).
"""

from __future__ import annotations

import numpy as np
from scipy import signal

from ...estimation.filters import (
    closed_loop_response,
    delay_signal,
    discretize,
    instrument_continuous_poly,
    svf_continuous,
)
from ...model import SubmodelStructure, modal_from_theta, modal_std
from .types import IdentificationResult, OfflineData, column_norms, equilibrated_solve

UNSTABLE_RADIUS = 1.0 + 1e-9   # |lambda| above this is cancelled; integrator poles (|lambda| = 1) are not


class _Param:
    """Anti-monic ([UNS-SRIVC] eq. 1) or monic ([UNS-SRIVC] §6 solution 1) parametrization of ``B/(p^l A)``."""

    def __init__(self, st: SubmodelStructure, monic: bool):
        if monic and st.integrators:
            raise ValueError("the monic parametrization (solution 1) models integrators through a_0; "
                             "use integrators = 0 with it")
        self.st, self.monic = st, monic

    def den(self, theta: np.ndarray) -> np.ndarray:
        n = self.st.n
        return np.concatenate((theta[:n], [1.0])) if self.monic else np.concatenate(([1.0], theta[:n]))

    def num(self, theta: np.ndarray) -> np.ndarray:
        return theta[self.st.n:]

    @property
    def y_index(self) -> int:
        """Which ``p^j/A y`` is the filtered output (j = 0 anti-monic, j = n monic)."""
        return self.st.n if self.monic else 0

    @property
    def a_indices(self) -> np.ndarray:
        n = self.st.n
        return np.arange(n) if self.monic else np.arange(1, n + 1)

    def to_antimonic(self, theta: np.ndarray) -> np.ndarray | None:
        if not self.monic:
            return theta
        a0 = theta[0]
        if a0 == 0:
            return None
        return np.concatenate((np.asarray(theta[1: self.st.n]) / a0, [1.0 / a0], np.asarray(self.num(theta)) / a0))


class _Bank:
    """``AP [p^j/(p^l D)]_ZOH`` for j = 0..order, as stable discrete filters in q^-1 ([UNS-SRIVC] eqs. 21-22)."""

    def __init__(self, den: np.ndarray, integrators: int, h: float, lam_u: np.ndarray | None = None):
        dss = discretize(*svf_continuous(den, integrators), h)
        self.rows = []
        A_d = np.real(np.poly(np.linalg.eigvals(dss.phi))) if dss.n_states else np.array([1.0])
        if lam_u is None:
            lam = np.roots(A_d) if A_d.size > 1 else np.zeros(0)
            lam_u = lam[np.abs(lam) > UNSTABLE_RADIUS]
        self.lam_u = lam_u
        # denominator with the unstable roots reflected: A_ds * Abar_da
        roots = np.roots(A_d) if A_d.size > 1 else np.zeros(0)
        refl = roots.copy()
        for lu in lam_u:
            k = int(np.argmin(np.abs(refl - lu)))
            refl[k] = 1.0 / lu
        self.den = np.real(np.poly(refl)) if refl.size else np.array([1.0])
        for j in range(dss.c.shape[0]):
            if dss.n_states:
                num, _ = signal.ss2tf(dss.phi, dss.gamma[:, None], dss.c[j][None, :], np.array([[dss.d[j]]]))
                num = np.real(num[0])
            else:
                num = np.array([dss.d[j]])
            self.rows.append(num)

    def run(self, v: np.ndarray, idx) -> np.ndarray:
        return np.column_stack([signal.lfilter(self.rows[j], self.den, v) for j in idx])


def _unstable_roots(par: _Param, theta: np.ndarray, h: float) -> np.ndarray:
    dss = discretize(*svf_continuous(par.den(theta), 0), h)
    lam = np.linalg.eigvals(dss.phi) if dss.n_states else np.zeros(0)
    return lam[np.abs(lam) > UNSTABLE_RADIUS]


def _signals(data: OfflineData, par: _Param, theta: np.ndarray, lam_u=None):
    """Filtered output ([UNS-SRIVC] eq. 21), regressor (eq. 22) and the prefiltered residual (eq. 19)."""
    st, h = par.st, data.h
    den = par.den(theta)
    if lam_u is None:
        lam_u = _unstable_roots(par, theta, h)
    by = _Bank(den, 0, h, lam_u)
    bu = _Bank(den, st.integrators, h, lam_u)
    fy = by.run(data.y, range(st.n + 1))
    fu = bu.run(data.u, range(st.m + 1))
    yf = fy[:, par.y_index]
    Phi = np.hstack((-fy[:, par.a_indices], fu))
    eps = yf - Phi @ theta
    return yf, Phi, eps, by, bu, lam_u


def _instrument_srivc(data: OfflineData, par: _Param, theta: np.ndarray, lam_u: np.ndarray,
                      Phi: np.ndarray) -> np.ndarray:
    """[UNS-SRIVC] eq. 26: ``d yhat / d theta``. Without unstable poles to cancel it is the exact ZOH gradient
    ``[-p^j B/(p^l A^2) u, p^j/(p^l A) u]`` ([A-SRIVC] eq. 10/31); otherwise central differences of the stable
    prefiltered residual ([UNS-SRIVC] §7.1: the a-part would need ``1/A^2``, which one all-pass cannot stabilize)."""
    if lam_u.size == 0:
        ins = discretize(*instrument_continuous_poly(par.den(theta), par.num(theta), par.st.integrators),
                         data.h).run(data.u)
        return np.hstack((-ins[:, par.a_indices], Phi[:, par.a_indices.size:]))
    cols = []
    for j in range(theta.size):
        dh = 1e-6 * max(abs(theta[j]), 1e-3)
        tp, tm = theta.copy(), theta.copy()
        tp[j] += dh
        tm[j] -= dh
        ep = _signals(data, par, tp, _unstable_roots(par, tp, data.h))[2]
        em = _signals(data, par, tm, _unstable_roots(par, tm, data.h))[2]
        cols.append(-(ep - em) / (2 * dh))
    return np.column_stack(cols)


def _instrument_clsrivc(data: OfflineData, par: _Param, theta: np.ndarray, by, bu) -> np.ndarray:
    """[UNS-SRIVC] eqs. 28-29 with a discrete controller: ``AP [-p^j/A T_o r, p^j/(p^l A) S_uo r]``."""
    at = par.to_antimonic(theta)
    if at is None:
        # monic with a_0 = 0: A = p (a_1 + .. + p^(n-1)) -> the forced-integrator form B'/(p A'), anti-monic A'
        a1 = theta[1] if par.st.n > 1 else 1.0
        if a1 == 0:
            raise np.linalg.LinAlgError("degenerate monic denominator (a_0 = a_1 = 0)")
        st_sim = SubmodelStructure(n=par.st.n - 1, m=par.st.m, integrators=1)
        th_sim = np.concatenate((theta[2: par.st.n] / a1, [1.0 / a1] if par.st.n > 1 else [], par.num(theta) / a1))
        sts, ths = [st_sim], [th_sim]
    else:
        sts, ths = [SubmodelStructure(n=par.st.n, m=par.st.m, integrators=par.st.integrators)], [at]
    controller, r = data.loop()
    z, ycl = closed_loop_response(ths, sts, data.h, controller, r, data.delay, check=True)
    z = delay_signal(z, data.delay)
    fa = by.run(ycl, par.a_indices)
    fb = bu.run(z, range(par.st.m + 1))
    return np.hstack((-fa, fb))


def _regression(base: str, data: OfflineData, par, theta: np.ndarray) -> tuple[np.ndarray, ...]:
    """Filtered output, regressor, output error, the method's instrument (LSSVF: the regressor itself) and the
    unstable poles cancelled by the all-pass prefilter."""
    yf, Phi, eps, by, bu, lam_u = _signals(data, par, theta)
    if base == "lssvf-uns":
        Z = Phi
    elif base == "srivc-uns":
        Z = _instrument_srivc(data, par, theta, lam_u, Phi)
    else:
        Z = _instrument_clsrivc(data, par, theta, by, bu)
    return yf, Phi, eps, Z, lam_u


def identify_unstable(data: OfflineData, structures, thetas0, *, method: str, max_iterations: int = 50,
                      tol: float = 1e-7) -> IdentificationResult:
    """Dispatch of the [UNS-SRIVC] estimators (K = 1); returns an :class:`types.IdentificationResult`."""
    from ...estimation.filters import ClosedLoopUnstableError

    if len(structures) != 1:
        raise ValueError(f"{method} estimates one unfactored submodel (K = 1), got {len(structures)}")
    st = structures[0]
    if st.n == 0:
        raise ValueError(f"{method} needs a denominator (n >= 1)")
    monic = method.endswith("-monic")
    par = _Param(st, monic)
    base = method.removesuffix("-monic")
    theta = np.asarray(thetas0[0], float).copy()
    if base == "clsrivc-uns":
        try:
            _instrument_clsrivc(data, par, theta, *_signals(data, par, theta)[3:5])
        except ClosedLoopUnstableError as exc:
            raise ClosedLoopUnstableError(f"{method}: the controller does not stabilize the initial model ({exc})") \
                from None
    scale = np.where(np.abs(theta) > 0, np.abs(theta), 1.0)
    converged, message, it, cond = False, "", 0, np.nan
    iters = 1 if base == "lssvf-uns" else max_iterations
    for it in range(1, iters + 1):
        try:
            yf, Phi, eps, Z, _ = _regression(base, data, par, theta)
            X, cond = equilibrated_solve(Z.T @ Phi, (Z.T @ yf)[:, None], column_norms(Z),
                                          column_norms(Phi))
            new = X[:, 0]
        except (np.linalg.LinAlgError, ValueError) as exc:
            message = f"iteration {it}: {exc}"
            it -= 1
            break
        if not np.all(np.isfinite(new)):
            message = f"iteration {it}: non-finite estimate"
            it -= 1
            break
        change = np.linalg.norm((new - theta) / scale) / max(float(np.linalg.norm(theta / scale)), 1e-300)
        theta = new
        if base == "lssvf-uns":
            converged, message = True, "least squares (one step)"
            break
        if change < tol:
            converged, message = True, "converged"
            break
    else:
        message = f"no convergence within {max_iterations} iterations (last relative change {change:.3g})"
    # covariance at the estimate (sandwich form, [A-SRIVC] Theorem 1) with the final instrument
    N = data.n
    try:
        yf, Phi, eps, Z, lam_u = _regression(base, data, par, theta)
        P = np.linalg.inv(Z.T @ Phi)
        s2_eps = float(eps @ eps) / max(N - theta.size, 1)
        cov = s2_eps * P @ (Z.T @ Z) @ P.T
        cov = 0.5 * (cov + cov.T)
        g2 = float(np.prod(np.abs(lam_u)) ** 2) if lam_u.size else 1.0
        sigma2 = s2_eps / g2          # output-noise variance: eps = AP v, |AP| = prod |lambda|
        cost = float(eps @ eps) / N / g2
    except (np.linalg.LinAlgError, ValueError) as exc:
        P = cov = np.full((theta.size, theta.size), np.nan)
        sigma2 = cost = np.nan
        converged = False
        message += f"; covariance unavailable ({exc})"
    at = par.to_antimonic(theta)
    if at is not None and st.n == 2 and st.integrators == 0:
        modal = modal_from_theta(at, SubmodelStructure(n=2, m=st.m))
        # delta method through the monic -> anti-monic map (numerical Jacobian)
        if monic:
            J = np.zeros((at.size, theta.size))
            for j in range(theta.size):
                dh = 1e-7 * max(abs(theta[j]), 1e-6)
                tp = theta.copy()
                tp[j] += dh
                J[:, j] = (par.to_antimonic(tp) - at) / dh
            cov_a = J @ cov @ J.T
        else:
            cov_a = cov
        mstd = modal_std(at, cov_a, SubmodelStructure(n=2, m=st.m))
    elif not monic:
        modal = modal_from_theta(theta, st)
        mstd = modal_std(theta, cov, st)
    else:
        modal = np.array([np.nan, np.nan, np.nan])
        mstd = np.array([np.nan, np.nan, np.nan])
    if monic:
        message += " (monic layout theta = [a_0..a_(n-1), b_0..b_m], [UNS-SRIVC] §6 solution 1)"
    return IdentificationResult(
        method=method, structures=[st], thetas=[theta], covariances=[cov], covariance=cov, P=P, p_blocks=[P],
        residual_variance=sigma2, iterations=it, converged=converged, cond=cond, cost=cost,
        modal=np.atleast_2d(modal), modal_std=np.atleast_2d(mstd), projections=0, message=message, n_samples=N,
        extra={"unstable_poles_cancelled": int(_unstable_roots(par, theta, data.h).size)})
