"""Closed-form ZOH of second-order sections against the augmented matrix exponential (scipy) and, over the whole
admissible domain, against an extended-precision reference (``scripts/validate_zoh.py``, issue 17 item 2)."""

import numpy as np
import pytest
from scipy.linalg import expm

from additive_rsrivc_ros.core.estimation.zoh import companion, integrator_chain_zoh, second_order_zoh, zoh_matrices
from additive_rsrivc_ros.sim import zoh_reference as vz


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



def test_decimal_reference_matches_decimal_expm():
    """The closed-form reference equals the Taylor/squaring expm of the augmented matrix in decimal (independent)."""
    rng = np.random.default_rng(5)
    pts, _ = vz.sample_iterates(400, 11)
    norms = np.array([max(h / a2 * (1 + a1 + a2), h) for a1, a2, h in pts])
    pick = pts[norms < 30.0]
    assert len(pick) >= 40
    for a1, a2, h in pick[rng.permutation(len(pick))[:40]]:
        ref_phi, ref_gam, scale = vz.reference_zoh(a1, a2, h)
        e_phi, e_gam = vz.decimal_expm(a1, a2, h)
        got = np.concatenate((e_phi.ravel(), e_gam))
        want = np.concatenate((ref_phi.ravel(), ref_gam))
        assert np.all(np.abs(got - want) <= 1e-14 * scale), (a1, a2, h)


def test_property_finite_and_exact_over_admissible_domain():
    """2000 random admissible (a1, a2, h): under-, critically, over-damped, stiff (q h up to 1e4), a2 -> 0."""
    pts, cls = vz.sample_iterates(2000, 1)
    assert set(cls) == set(range(len(vz.CLASS_NAMES)))
    err, fin = vz.errors(pts)
    assert np.all(fin)
    assert err.max() <= 1e-9, (pts[np.argmax(err)], err.max())


@pytest.mark.parametrize("a1,a2,h", [
    (0.01, 3e-7, 0.05),        # issue 17: fast pole at -3.3e4 rad/s at 20 Hz (q h ~ 833, old form NaN)
    (0.01, 1e-9, 0.05),        # q h ~ 2.5e5: e^{lambda2 h} underflows to 0, first-order limit 1/(a1 p + 1)
    (2.0, 1e-300, 1.0),        # near-singular a2
    (0.25, 0.015625 * (1 - 1e-13), 50.0),    # near-critical damping (zeta - 1 ~ 5e-14), s h = -25
])
def test_stiff_iterates_are_finite_and_match_reference(a1, a2, h):
    phi, gam = np.zeros((2, 2)), np.zeros(2)
    second_order_zoh(a1, a2, h, phi, gam)
    ref_phi, ref_gam, scale = vz.reference_zoh(a1, a2, h)
    got = np.concatenate((phi.ravel(), gam))
    want = np.concatenate((ref_phi.ravel(), ref_gam))
    assert np.all(np.isfinite(got))
    assert np.all(np.abs(got - want) <= 1e-12 * np.maximum(scale, 1e-300))


def test_first_order_limit_of_a_stiff_mode():
    """a2 -> 0 with a1 fixed: 1/(a2 p^2 + a1 p + 1) -> 1/(a1 p + 1), w(h) = 1 - e^{-h/a1} for a unit step."""
    a1, h = 0.01, 0.05
    phi, gam = np.zeros((2, 2)), np.zeros(2)
    second_order_zoh(a1, 1e-20, h, phi, gam)  # O(a2/a1^2) = 1e-16 from the limit
    np.testing.assert_allclose(gam[0], -np.expm1(-h / a1), rtol=1e-12)
    np.testing.assert_allclose(phi[0, 0], np.exp(-h / a1), rtol=1e-12)


@pytest.mark.parametrize("a1,a2,h", [(0.01, 3e-7, 0.05), (0.25, 0.25, 0.05), (2.0, 1e-12, 1e-3), (0.0, 0.04, 0.05)])
@pytest.mark.parametrize("scale", [1.0, 37.0])
def test_zoh_matrices_of_second_order_companions_are_exact(a1, a2, h, scale):
    """zoh_matrices (used by core.filters for the offline filters) on a (scaled) companion form of 1/A(p) equals the
    reference in the same coordinates, also where the matrix exponential loses the stiff entries."""
    from additive_rsrivc_ros.core.estimation.filters import svf_continuous
    A = np.array([[0.0, scale], [-1.0 / (a2 * scale), -a1 / a2]])
    B = np.array([0.0, 1.0 / (a2 * scale)])
    phi, gam = zoh_matrices(A, B, h)
    ref_phi, ref_gam, sc = vz.reference_zoh(a1, a2, h)
    S = np.diag([1.0, 1.0 / scale])
    want_phi = S @ ref_phi @ np.linalg.inv(S)
    want_gam = S @ ref_gam
    got = np.concatenate((phi.ravel(), gam[:, 0]))
    want = np.concatenate((want_phi.ravel(), want_gam))
    coord = np.array([1.0, scale, 1.0 / scale, 1.0, 1.0, 1.0 / scale])    # the entries' natural scales, same coords
    assert np.all(np.abs(got - want) <= 1e-11 * np.maximum(sc * coord, 1e-300)), (got, want)
    A2, B2, _, _ = svf_continuous(np.array([1.0, a1, a2]))   # the realization the offline filters use
    p2, g2 = zoh_matrices(A2, B2, h)
    assert np.all(np.isfinite(p2)) and np.all(np.isfinite(g2))
