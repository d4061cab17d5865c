"""Test data for the offline estimators: ZOH-exact plant via scipy.signal.cont2discrete (independent of
core/filters.py) in an explicit causal closed loop. No tests here; imported by test_offline*.py."""

from __future__ import annotations

import numpy as np
from scipy import signal

from additive_rsrivc_ros.core.model import SubmodelStructure, total_transfer_function
from additive_rsrivc_ros.sim.plants import CL52_THETAS, PAPER_PID_DEN, PAPER_PID_NUM

MODE = SubmodelStructure(n=2, m=0, integrators=0)
# 001 §5.2 system (eq. 46) and PID (NOTES erratum 1)
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
    """MSE per parameter [a11, a12, b10, a21, a22, b20] of an independent implementation on the 001 §5.2
    closed-loop example (issue 3; h = 0.05, N = 10000, 50 runs)."""
    return np.array([1.03e-5, 2.98e-6, 1.26e-3, 1.12e-7, 2.00e-9, 3.96e-4])


def second_order_gradient_covariance(thetas, h: float, u: np.ndarray, noise_var: float,
                                     skip: int = 2000) -> np.ndarray:
    """Asymptotic covariance per sample (multiply by 1/N) of theta = [a1, a2, b0] per mode for white output
    noise: ``noise_var * E{psi psi^T}^-1`` with ``psi`` the gradient of ``sum_i b_i0/(a_i2 p^2 + a_i1 p + 1) u``
    (``-p B/A^2 u``, ``-p^2 B/A^2 u``, ``1/A u``), each ZOH-discretized by scipy.

    With ``u`` the noise-free closed-loop input ``S_uo r`` this is 001 Theorem 1 with the optimal instrument
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
