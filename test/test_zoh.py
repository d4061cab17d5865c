"""Closed-form ZOH of second-order sections against the augmented matrix exponential (scipy)."""
import numpy as np
import pytest
from scipy.linalg import expm

from additive_rsrivc_ros.core.zoh import companion, integrator_chain_zoh, second_order_zoh, zoh_matrices


def _reference(a1: float, a2: float, h: float) -> tuple[np.ndarray, np.ndarray]:
    A, B = companion(np.array([1.0, a1, a2]))
    aug = np.zeros((3, 3))
    aug[:2, :2], aug[:2, 2] = A * h, B * h
    e = expm(aug)
    return e[:2, :2], e[:2, 2]


CASES = [  # (f_hz, zeta, rate_hz): light damping, high rate, over/critical damping, paper example
    (3.25, 0.235, 4096.0), (33.0, 0.017, 4096.0), (183.0, 0.002, 4096.0), (171.7, 0.0056, 4096.0),
    (0.318, 0.25, 20.0), (3.18, 0.1, 20.0), (5.0, 1.0, 100.0), (5.0, 1.0 + 1e-9, 100.0), (5.0, 3.0, 100.0),
    (0.01, 0.5, 4096.0), (1000.0, 0.05, 4096.0),
]


@pytest.mark.parametrize("f,zeta,rate", CASES)
def test_second_order_matches_expm(f, zeta, rate):
    w = 2 * np.pi * f
    a1, a2, h = 2 * zeta / w, 1 / w**2, 1 / rate
    phi, gam = np.zeros((2, 2)), np.zeros(2)
    second_order_zoh(a1, a2, h, phi, gam)
    phi_r, gam_r = _reference(a1, a2, h)
    # expm itself is accurate to a few ulp of the largest entry per row; compare relative to row scale
    np.testing.assert_allclose(phi, phi_r, rtol=1e-12, atol=1e-14 * np.abs(phi_r).max())
    np.testing.assert_allclose(gam, gam_r, rtol=1e-10, atol=0)


def test_unstable_and_negative_coefficients_are_still_exact():
    for a1, a2 in [(-0.01, 0.04), (0.02, -0.04), (-0.3, -0.02)]:
        phi, gam = np.zeros((2, 2)), np.zeros(2)
        second_order_zoh(a1, a2, 0.05, phi, gam)
        phi_r, gam_r = _reference(a1, a2, 0.05)
        np.testing.assert_allclose(phi, phi_r, rtol=1e-11)
        np.testing.assert_allclose(gam, gam_r, rtol=1e-10)


@pytest.mark.parametrize("l", [1, 2, 3])
def test_integrator_chain(l):
    h = 1 / 4096
    phi, gam = np.zeros((l, l)), np.zeros(l)
    integrator_chain_zoh(l, h, phi, gam)
    A, B = companion(np.array([1.0]), integrators=l)
    phi_r, gam_r = zoh_matrices(A, B, h)
    np.testing.assert_allclose(phi, phi_r, rtol=1e-13, atol=1e-300)
    np.testing.assert_allclose(gam, gam_r[:, 0], rtol=1e-13)


def test_step_response_settles_to_dc_gain():
    """Many steps of a unit input drive w to 1 (A(0) = 1) and w' to 0: Gamma and Phi are consistent."""
    a1, a2, h = 2 * 0.2 / 20.0, 1 / 400.0, 0.01
    phi, gam = np.zeros((2, 2)), np.zeros(2)
    second_order_zoh(a1, a2, h, phi, gam)
    x = np.zeros(2)
    for _ in range(5000):
        x = phi @ x + gam
    np.testing.assert_allclose(x, [1.0, 0.0], atol=1e-12)
