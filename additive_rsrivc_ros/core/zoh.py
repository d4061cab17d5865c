"""Exact zero-order-hold discretization of the small state-variable filters (numba-compiled).

../shared/NOTES.md: the prefilters must be ZOH-exact (Tustin biased the closed-loop estimates by 1-4
standard deviations). Every filter of the SRIVC family is built from the second-order section

    a2 w'' + a1 w' + w = v(t),   v held constant on [t_k, t_k + h)          (000 eqs. 26-28)

in physical coordinates ``x = [w, w']``; ``x_{k+1} = Phi x_k + Gamma v_k``. The filter outputs at t_k are
``1/A v = w``, ``p/A v = w'`` and ``p^2/A v = (v_k - w - a1 w') / a2`` (direct term). Physical
coordinates keep the state meaningful when the coefficients change from one sample to the next (the
slow-variation approximation of 000 Remark 4.4), which is how the recursive engine and the simulator
carry filter states.

The closed form uses ``expm(M h) = e^{s h} [c I + S (M - s I)]`` with ``s = tr(M)/2``,
``q^2 = s^2 - det(M)``, ``c = cosh(q h)``, ``S = sinh(q h)/q`` (trigonometric when ``q^2 < 0``; a series
near ``q = 0``), and ``Gamma = [1 - Phi_11, -Phi_21]`` (the step response). ``1 - Phi_11`` is evaluated
with ``expm1`` and half-angle forms, so that a 3 Hz mode at 4096 Hz or a 183 Hz mode with zeta = 0.002
keeps full relative precision.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True)
def _c_s_1mc(q2: float, h: float) -> tuple[float, float, float]:
    """``c = cosh(q h)``, ``S = sinh(q h)/q`` and ``1 - c`` for real or imaginary ``q`` (q2 = q^2)."""
    x2 = q2 * h * h
    if abs(x2) < 1e-2:
        # series: c = sum x2^k/(2k)!, S = h sum x2^k/(2k+1)!  (error < 1e-2^6/12! ~ 2e-21)
        one_minus_c = -(x2 / 2.0) * (1.0 + x2 / 12.0 * (1.0 + x2 / 30.0 * (1.0 + x2 / 56.0 * (1.0 + x2 / 90.0))))
        s_over = h * (1.0 + x2 / 6.0 * (1.0 + x2 / 20.0 * (1.0 + x2 / 42.0 * (1.0 + x2 / 72.0))))
        return 1.0 - one_minus_c, s_over, one_minus_c
    if q2 > 0.0:
        q = math.sqrt(q2)
        half = math.sinh(0.5 * q * h)
        return math.cosh(q * h), math.sinh(q * h) / q, -2.0 * half * half
    wd = math.sqrt(-q2)
    half = math.sin(0.5 * wd * h)
    return math.cos(wd * h), math.sin(wd * h) / wd, 2.0 * half * half


@njit(cache=True)
def second_order_zoh(a1: float, a2: float, h: float, phi: np.ndarray, gamma: np.ndarray) -> None:
    """Fill ``phi`` (2x2) and ``gamma`` (2,) with the exact ZOH of ``a2 w'' + a1 w' + w = v``.

    Requires ``a2 != 0``. Valid for any damping (under-, critically, over-damped) and for unstable
    coefficients as well (the caller projects those first, 000 §4.7).
    """
    s = -0.5 * a1 / a2
    q2 = s * s - 1.0 / a2
    c, sv, one_minus_c = _c_s_1mc(q2, h)
    e = math.exp(s * h)
    em1 = math.expm1(s * h)
    phi[0, 0] = e * (c - s * sv)
    phi[0, 1] = e * sv
    phi[1, 0] = -e * sv / a2
    phi[1, 1] = e * (c + s * sv)
    # 1 - e (c - s S) = (1 - c) + s S - em1 (c - s S)
    gamma[0] = one_minus_c + s * sv - em1 * (c - s * sv)
    gamma[1] = e * sv / a2


@njit(cache=True)
def integrator_chain_zoh(l: int, h: float, phi: np.ndarray, gamma: np.ndarray) -> None:
    """Exact ZOH of ``1/p^l`` in coordinates ``[w, w', ..., w^(l-1)]``: ``Phi_ij = h^(j-i)/(j-i)!``."""
    for i in range(l):
        for j in range(l):
            phi[i, j] = h ** (j - i) / math.gamma(j - i + 1.0) if j >= i else 0.0
        gamma[i] = h ** (l - i) / math.gamma(l - i + 1.0)


def zoh_matrices(a: np.ndarray, b: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Generic exact ZOH of ``x' = a x + b v`` via the augmented matrix exponential (any order)."""
    from scipy.linalg import expm  # lazy: keeps the kernel's import (and the node's start) fast

    a = np.atleast_2d(np.asarray(a, dtype=float))
    b = np.asarray(b, dtype=float).reshape(a.shape[0], -1)
    n, m = b.shape
    aug = np.zeros((n + m, n + m))
    aug[:n, :n] = a * h
    aug[:n, n:] = b * h
    e = expm(aug)
    return e[:n, :n], e[:n, n:]


def companion(a_poly: np.ndarray, integrators: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """State-space ``(A, B)`` of ``1/(p^l A(p))`` in coordinates ``[w, w', ..., w^(N-1)]``.

    ``a_poly`` holds A's coefficients in ascending powers (``a_poly[0] = 1`` anti-monic);
    N = l + deg A. The outputs ``p^j/(p^l A) v`` for j < N are the states.
    """
    a_poly = np.asarray(a_poly, dtype=float)
    den = np.concatenate((np.zeros(integrators), a_poly))  # ascending powers of p^l A(p)
    n = den.size - 1
    if n < 1:
        raise ValueError("filter must have order >= 1")
    lead = den[-1]
    if lead == 0.0:
        raise ValueError("leading coefficient of A is zero")
    A = np.zeros((n, n))
    A[:-1, 1:] = np.eye(n - 1)
    A[-1, :] = -den[:-1] / lead
    B = np.zeros(n)
    B[-1] = 1.0 / lead
    return A, B
