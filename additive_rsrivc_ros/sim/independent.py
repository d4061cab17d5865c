"""An independent simulator for validating the offline estimators: ZOH-exact plant via scipy.signal.cont2discrete
(independent of core/estimation/filters.py and core/plant.py) in an explicit causal closed loop, the [A-SRIVC] §5.2
reference
figures and the asymptotic covariance of the experiment. Used by test/test_offline*.py and scripts/validate_offline.py,
never by the product; and ``simulate_modal``, a plain reference plant for the recursive engine's tests (modes
``b0/(a2 p^2 + a1 p + 1)`` or a rigid body ``b0/p^l`` in physical coordinates, ZOH input, optional input delay and
closed loop ``u_k = C_d(q)(r_k - y_k)``, parameters piecewise constant between samples, [RA-SRIVC] Assumption 5)."""

from __future__ import annotations

import numpy as np
from numba import njit
from scipy import signal

from ..core.estimation.compiled import ensure_jit
from ..core.estimation.zoh import integrator_chain_zoh, second_order_zoh
from ..core.model import SubmodelStructure, total_transfer_function
from .plants import CL52_THETAS, PAPER_PID, PAPER_PID_DEN, PAPER_PID_NUM
from .plants import PAPER_THETAS as PAPER5_THETAS

MODE = SubmodelStructure(n=2, m=0, integrators=0)
# [A-SRIVC] §5.2 system (eq. 46) and PID (erratum 1 in docs/DESIGN.md)
PAPER_THETAS = CL52_THETAS
PID_NUM = PAPER_PID_NUM
PID_DEN = PAPER_PID_DEN


def zoh_tf(thetas, structures, h: float, delay: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """ZOH equivalent (ascending powers of q^-1) of the additive model, times q^-delay."""
    num, den = total_transfer_function(thetas, structures)
    numd, dend, _ = signal.cont2discrete((num[::-1], den[::-1]), h, method="zoh")
    numd = np.atleast_1d(numd.ravel())
    numd = np.concatenate((np.zeros(delay), numd))
    dend = np.concatenate((dend, np.zeros(delay)))
    return numd / dend[0], dend / dend[0]


def simulate(thetas, structures, h, *, u=None, r=None, controller=None, noise=None, delay=0):
    """Open loop (``u`` given) or closed loop (``r`` and controller (num, den) in q^-1) data ``(u, y)``.

    ``y = G_d q^-d u + noise``; closed loop ``u = C_d (r - y)`` computed sample by sample.
    """
    bd, ad = zoh_tf(thetas, structures, h, delay)
    n = len(u) if u is not None else len(r)
    v = np.zeros(n) if noise is None else np.asarray(noise, float)
    if u is not None:
        return np.asarray(u, float), signal.lfilter(bd, ad, u) + v
    cn, cd = (np.asarray(c, float) for c in controller)
    assert bd[0] == 0.0  # strictly proper: no algebraic loop
    uu, xx, yy = np.zeros(n), np.zeros(n), np.zeros(n)
    nb, na, ncn, ncd = len(bd), len(ad), len(cn), len(cd)
    for k in range(n):
        acc = 0.0
        for i in range(1, nb):
            if k - i >= 0:
                acc += bd[i] * uu[k - i]
        for i in range(1, na):
            if k - i >= 0:
                acc -= ad[i] * xx[k - i]
        xx[k] = acc
        yy[k] = acc + v[k]
        e_acc = 0.0
        for i in range(ncn):
            if k - i >= 0:
                e_acc += cn[i] * (r[k - i] - yy[k - i])
        for i in range(1, ncd):
            if k - i >= 0:
                e_acc -= cd[i] * uu[k - i]
        uu[k] = e_acc / cd[0]
    return uu, yy


def cl52_reference_mse() -> np.ndarray:
    """MSE per parameter [a11, a12, b10, a21, a22, b20] of an independent implementation on the [A-SRIVC] §5.2
    closed-loop example (h = 0.05, N = 10000, 50 runs)."""
    return np.array([1.03e-5, 2.98e-6, 1.26e-3, 1.12e-7, 2.00e-9, 3.96e-4])


def second_order_gradient_covariance(thetas, h: float, u: np.ndarray, noise_var: float,
                                     skip: int = 2000) -> np.ndarray:
    """Asymptotic covariance per sample (multiply by 1/N) of theta = [a1, a2, b0] per mode for white output
    noise: ``noise_var * E{psi psi^T}^-1`` with ``psi`` the gradient of ``sum_i b_i0/(a_i2 p^2 + a_i1 p + 1) u``
    (``-p B/A^2 u``, ``-p^2 B/A^2 u``, ``1/A u``), each ZOH-discretized by scipy.

    With ``u`` the noise-free closed-loop input ``S_uo r`` this is [A-SRIVC] Theorem 1 with the optimal instrument
    (Corollary 1, eq. 15): the best any instrumental-variable estimator of the closed loop can do. With the
    measured ``u`` (fed-back noise included) it is the Cramer-Rao bound of the direct output-error approach.
    """
    def zf(num, den):
        b, a, _ = signal.cont2discrete((num, den), h, method="zoh")
        b = np.atleast_1d(b.ravel())
        return signal.lfilter(b / a[0], a / a[0], u)

    cols = []
    for a1, a2, b0 in thetas:
        a_poly = np.array([a2, a1, 1.0])
        a_sq = np.polymul(a_poly, a_poly)
        cols += [zf([-b0, 0.0], a_sq), zf([-b0, 0.0, 0.0], a_sq), zf([1.0], a_poly)]
    psi = np.array(cols).T[skip:]
    return noise_var * np.linalg.inv(psi.T @ psi / len(psi))


PID = PAPER_PID  # erratum 1 in docs/DESIGN.md
PAPER_THETA = PAPER5_THETAS   # the [RA-SRIVC] §5 plant (PAPER_THETAS above: the [A-SRIVC] §5.2 system)


@njit(cache=False)
def _sim(theta_traj, kinds, h, delay, closed, cnum, cden, r, u_ext, noise):  # pragma: no cover - compiled
    n, K = theta_traj.shape[0], theta_traj.shape[1]
    x = np.zeros((K, 2))
    phi = np.zeros((2, 2))
    gam = np.zeros(2)
    ubuf = np.zeros(delay + 1)
    ce = np.zeros(cnum.size)
    cz = np.zeros(cden.size)
    u = np.zeros(n)
    y = np.zeros(n)
    pos = 0
    for k in range(n):
        yk = 0.0
        for i in range(K):
            ib = 2 if kinds[i] == 0 else 0
            yk += theta_traj[k, i, ib] * x[i, 0]
        y[k] = yk + noise[k]
        if closed:
            e = r[k] - y[k]
            for j in range(ce.size - 1, 0, -1):
                ce[j] = ce[j - 1]
            ce[0] = e
            uk = 0.0
            for j in range(cnum.size):
                uk += cnum[j] * ce[j]
            for j in range(1, cden.size):
                uk -= cden[j] * cz[j - 1]
            for j in range(cz.size - 1, 0, -1):
                cz[j] = cz[j - 1]
            cz[0] = uk
        else:
            uk = u_ext[k]
        u[k] = uk
        ubuf[pos] = uk
        pos = (pos + 1) % (delay + 1)
        ud = ubuf[pos]  # u_{k-d}
        for i in range(K):
            phi[:, :] = 0.0
            gam[:] = 0.0
            if kinds[i] == 0:
                second_order_zoh(theta_traj[k, i, 0], theta_traj[k, i, 1], h, phi, gam)
            else:
                integrator_chain_zoh(kinds[i], h, phi[:kinds[i], :kinds[i]], gam[:kinds[i]])
            x0 = phi[0, 0] * x[i, 0] + phi[0, 1] * x[i, 1] + gam[0] * ud
            x1 = phi[1, 0] * x[i, 0] + phi[1, 1] * x[i, 1] + gam[1] * ud
            x[i, 0] = x0
            x[i, 1] = x1
    return u, y


def simulate_modal(theta, rate_hz, n, *, r=None, u=None, controller=None, delay=0, noise_std=0.0, seed=0,
                   kinds=None):
    """Return ``(u, y)``: theta is a list of K vectors (constant) or an array (n, K, 3) (time-varying)."""
    if isinstance(theta, list):
        traj = np.zeros((n, len(theta), 3))
        for i, t in enumerate(theta):
            traj[:, i, :len(t)] = t
    else:
        traj = np.ascontiguousarray(theta, dtype=float)
    K = traj.shape[1]
    kinds = np.zeros(K, dtype=np.int64) if kinds is None else np.asarray(kinds, dtype=np.int64)
    closed = controller is not None
    cnum = controller.num if closed else np.zeros(1)
    cden = controller.den if closed else np.ones(1)
    rng = np.random.default_rng(seed)
    noise = noise_std * rng.standard_normal(n)
    r = np.zeros(n) if r is None else np.asarray(r, dtype=float)
    u_ext = np.zeros(n) if u is None else np.asarray(u, dtype=float)
    ensure_jit()       # _sim calls the package's ZOH kernels, which then must be numba dispatchers
    return _sim(traj, kinds, 1.0 / rate_hz, int(delay), closed, np.asarray(cnum, float), np.asarray(cden, float),
                r, u_ext, noise)


def paper_reference(t):
    """[RA-SRIVC] §5 setpoint ``3 sin(0.005 t) + sin 2t + sin 5t + sin 17.5t``."""
    return 3 * np.sin(0.005 * t) + np.sin(2 * t) + np.sin(5 * t) + np.sin(17.5 * t)
