"""Additive continuous-time model structure and modal conversions.

Conventions (papers [RA-SRIVC] eq. 5-7, [A-SRIVC] eq. 2-3, docs/DESIGN.md "Conventions"):

* Submodel i is ``B_i(p) / (p^l_i A_i(p))`` with ``A_i(p) = 1 + a_i1 p + ... + a_in p^n`` (anti-monic)
  and ``B_i(p) = b_i0 + b_i1 p + ... + b_im p^m``; ``l_i`` poles at the origin only where declared
  (rigid-body modes, [RA-SRIVC] §4.6, [A-SRIVC] Remark 6). At most one submodel may be biproper (m = n, l = 0).
* Parameter vector ``theta_i = [a_i1 .. a_in, b_i0 .. b_im]`` ([RA-SRIVC] eq. 7); the stacked vector over
  all submodels is ``beta`` ([RA-SRIVC] eq. 8).
* A second-order mode ``b0 / (a2 p^2 + a1 p + 1)`` has ``omega = 1/sqrt(a2)`` rad/s,
  ``zeta = a1 / (2 sqrt(a2))`` and DC gain ``b0`` ([RA-SRIVC] Example 3.3, eq. 16). Frequencies are published
  in Hz. A pure rigid-body mode ``b0 / p^l`` (n = 0) reports frequency 0, damping 0 and gain b0.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

TWO_PI = 2.0 * np.pi


@dataclass(frozen=True)
class SubmodelStructure:
    """Orders of one additive submodel ``B(p) / (p^integrators A(p))``."""

    n: int = 2
    m: int = 0
    integrators: int = 0

    def __post_init__(self) -> None:
        if self.n < 0 or self.m < 0 or self.integrators < 0:
            raise ValueError(f"submodel orders must be non-negative, got {self}")
        if self.m > self.n + self.integrators:
            raise ValueError(f"improper submodel: m={self.m} > n+integrators={self.n + self.integrators}")

    @property
    def n_theta(self) -> int:
        """Number of parameters ``n + m + 1`` ([RA-SRIVC] §2.2)."""
        return self.n + self.m + 1

    @property
    def is_biproper(self) -> bool:
        return self.m == self.n + self.integrators

    @property
    def is_mode(self) -> bool:
        """True for a second-order resonance ``b0/(a2 p^2 + a1 p + 1)`` (possibly with integrators)."""
        return self.n == 2 and self.m == 0


def split_theta(theta: np.ndarray, s: SubmodelStructure) -> tuple[np.ndarray, np.ndarray]:
    """Return the polynomial coefficients ``(A, B)`` in ascending powers of p (A[0] = 1)."""
    theta = np.asarray(theta, dtype=float)
    if theta.shape != (s.n_theta,):
        raise ValueError(f"theta has shape {theta.shape}, structure {s} needs ({s.n_theta},)")
    a = np.concatenate(([1.0], theta[: s.n]))
    b = theta[s.n:].copy()
    return a, b


def theta_from_modal(natural_frequency_hz: float, damping_ratio: float, gain: float) -> np.ndarray:
    """``theta = [a1, a2, b0]`` of the mode ``gain / (p^2/w^2 + 2 zeta p / w + 1)`` ([RA-SRIVC] eq. 16-17)."""
    if not natural_frequency_hz > 0.0:
        raise ValueError(f"natural frequency must be > 0 Hz, got {natural_frequency_hz}")
    w = TWO_PI * natural_frequency_hz
    return np.array([2.0 * damping_ratio / w, 1.0 / w**2, float(gain)])


def guess_structure(natural_frequency_hz: float, integrators: int = 0) -> SubmodelStructure:
    """Submodel of a modal guess: rigid body ``b0/p^l`` when the frequency is 0, else ``b0/(a2 p² + a1 p + 1)``."""
    if natural_frequency_hz == 0.0:
        return SubmodelStructure(n=0, m=0, integrators=integrators)
    return SubmodelStructure(n=2, m=0, integrators=integrators)


def guess_theta(natural_frequency_hz: float, damping_ratio: float, gain: float) -> np.ndarray:
    """θ ([RA-SRIVC] eq. 7) of a modal guess; a rigid body (frequency 0) has only ``b0``."""
    if natural_frequency_hz == 0.0:
        return np.array([float(gain)])
    return theta_from_modal(natural_frequency_hz, damping_ratio, gain)


def second_order_modal(a1: Any, a2: Any) -> tuple[Any, Any]:
    """``(f_hz, zeta)`` of the denominator ``a2 p^2 + a1 p + 1`` (``a2 > 0``): ``omega = 1/sqrt(a2)`` rad/s, ``zeta =
    a1 / (2 sqrt(a2))`` ([RA-SRIVC] eqs. 16-17). The one home of this arithmetic: scalars or arrays, and numba
    compiles it into the report kernel (core/estimation/report_numbers.py)."""
    sq = np.sqrt(a2)
    return 1.0 / (TWO_PI * sq), a1 / (2.0 * sq)


def second_order_modal_derivatives(a1: Any, a2: Any) -> tuple[Any, Any, Any]:
    """``(df/da2, dzeta/da1, dzeta/da2)`` of :func:`second_order_modal` (``df/da1 = 0``; the delta method's Jacobian,
    :func:`modal_jacobian`)."""
    return -0.5 / TWO_PI * a2**-1.5, 0.5 / np.sqrt(a2), -0.25 * a1 * a2**-1.5


def modal_from_theta(theta: np.ndarray, s: SubmodelStructure = SubmodelStructure()) -> np.ndarray:
    """``[natural_frequency_hz, damping_ratio, gain]`` of a submodel (NaN where a2 <= 0).

    For ``n = 2, m = 0`` this inverts :func:`theta_from_modal`; for ``n = 0`` (rigid body ``b0/p^l``)
    it returns ``[0, 0, b0]``; for ``n = 1`` it returns the corner frequency, damping 1 and ``b0``.
    """
    theta = np.asarray(theta, dtype=float)
    if s.n == 0:
        return np.array([0.0, 0.0, theta[0]])
    if s.n == 1:
        a1 = theta[0]
        f = 1.0 / (TWO_PI * a1) if a1 > 0 else np.nan
        return np.array([f, 1.0, theta[1]])
    a1, a2, b0 = theta[0], theta[1], theta[s.n]
    if not a2 > 0.0:
        return np.array([np.nan, np.nan, b0])
    f_hz, zeta = second_order_modal(a1, a2)
    return np.array([f_hz, zeta, b0])


def modal_jacobian(theta: np.ndarray, s: SubmodelStructure = SubmodelStructure()) -> np.ndarray:
    """Jacobian ``d[f, zeta, gain] / d theta`` (3 x n_theta) used by the delta method."""
    theta = np.asarray(theta, dtype=float)
    jac = np.zeros((3, s.n_theta))
    jac[2, s.n] = 1.0  # gain = b0
    if s.n == 1:
        a1 = theta[0]
        jac[0, 0] = -1.0 / (TWO_PI * a1**2) if a1 != 0 else np.nan
    elif s.n >= 2:
        a1, a2 = theta[0], theta[1]
        if a2 > 0.0:
            jac[0, 1], jac[1, 0], jac[1, 1] = second_order_modal_derivatives(a1, a2)
        else:
            jac[:2, :2] = np.nan
    return jac


def modal_std(theta: np.ndarray, cov: np.ndarray, s: SubmodelStructure = SubmodelStructure()) -> np.ndarray:
    """Standard deviations of ``[f_hz, zeta, gain]`` by the delta method: ``sqrt(diag(J C J^T))``.

    A negative variance (an indefinite ``C``) gives NaN, never a silent 0. For a second-order
    mode ``J`` has ``df/da2 = -(1/(4 pi)) a2^-3/2``, ``dzeta/da1 = 1/(2 sqrt a2)``, ``dzeta/da2 = -a1/(4 a2^3/2)``,
    ``dgain/db0 = 1`` (:func:`modal_jacobian`); first order, so valid while the relative std is small.
    """
    jac = modal_jacobian(theta, s)
    var = np.einsum("ij,jk,ik->i", jac, np.asarray(cov, dtype=float), jac)
    with np.errstate(invalid="ignore"):
        return np.where(var >= 0.0, np.sqrt(np.abs(var)), np.nan)


def frequency_response(
    thetas: list[np.ndarray], structures: list[SubmodelStructure], freqs_hz: np.ndarray,
    delay_s: float = 0.0,
) -> np.ndarray:
    """Complex response ``sum_i B_i(jw) / ((jw)^l_i A_i(jw))`` times ``exp(-jw delay_s)``."""
    s = 1j * TWO_PI * np.asarray(freqs_hz, dtype=float)
    total = np.zeros_like(s)
    for theta, st in zip(thetas, structures, strict=True):
        a, b = split_theta(theta, st)
        total = total + np.polyval(b[::-1], s) / (s**st.integrators * np.polyval(a[::-1], s))
    return total * np.exp(-s * delay_s)


def total_transfer_function(
    thetas: list[np.ndarray], structures: list[SubmodelStructure],
) -> tuple[np.ndarray, np.ndarray]:
    """The additive model as one ``B(p)/A(p)``; coefficients in ascending powers of p ([A-SRIVC] eq. 1)."""
    num = np.zeros(1)
    den = np.ones(1)
    for theta, st in zip(thetas, structures, strict=True):
        a, b = split_theta(theta, st)
        ai = np.concatenate((np.zeros(st.integrators), a))
        num = np.polynomial.polynomial.polyadd(
            np.polynomial.polynomial.polymul(num, ai), np.polynomial.polynomial.polymul(b, den))
        den = np.polynomial.polynomial.polymul(den, ai)
    return num, den


def parallel_state_space(blocks: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]]
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The additive model ([RA-SRIVC] eq. 7: one input, the submodels' outputs summed) as one state space from each
    submodel's ``(Phi_i, Gamma_i, c_i)``: block-diagonal ``Phi``, stacked ``Gamma`` and ``c`` (without
    ``scipy.linalg.block_diag``, 0.2 s to import)."""
    nx = sum(np.shape(phi)[0] for phi, _, _ in blocks)
    phi_all, gam_all, c_all = np.zeros((nx, nx)), np.zeros(nx), np.zeros(nx)
    i = 0
    for phi, gam, c in blocks:
        k = np.shape(phi)[0]
        phi_all[i:i + k, i:i + k] = phi
        gam_all[i:i + k] = np.ravel(gam)
        c_all[i:i + k] = np.ravel(c)
        i += k
    return phi_all, gam_all, c_all


def reflect_unstable(a: np.ndarray) -> tuple[np.ndarray, bool]:
    """Reflect right-half-plane roots of an anti-monic ``A(p)`` (ascending) into the LHP ([RA-SRIVC] §4.7).

    Returns the projected polynomial (still anti-monic) and whether anything was reflected.
    """
    a = np.asarray(a, dtype=float)
    if a.size <= 1:
        return a.copy(), False
    roots = np.roots(a[::-1])
    bad = roots.real >= 0.0
    if not np.any(bad):
        return a.copy(), False
    roots = np.where(bad, -np.abs(roots.real) + 1j * roots.imag, roots)
    roots = np.where(roots.real == 0.0, roots - 1e-12, roots)
    # A(p) = prod(1 - p / r_k): rebuild with constant term 1
    poly = np.array([1.0 + 0j])
    for r in roots:
        poly = np.polynomial.polynomial.polymul(poly, np.array([1.0, -1.0 / r]))
    return poly.real.copy(), True
