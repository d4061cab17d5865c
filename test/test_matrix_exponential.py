"""The matrix exponential of :mod:`core.matrix_exponential`: exact cases, the group property, and scipy's
``expm`` (the reference the filters used before; the module exists to spare its import)."""

import numpy as np
import pytest
from scipy.linalg import expm as scipy_expm

from additive_rsrivc_ros.core.matrix_exponential import expm


def _rel(a, b):
    return np.linalg.norm(a - b, 1) / max(np.linalg.norm(b, 1), 1e-300)


@pytest.mark.parametrize("scale", [1e-6, 1e-2, 0.2, 0.9, 2.0, 5.0, 30.0, 300.0])
def test_matches_scipy_over_every_pade_degree_and_scaling(scale):
    rng = np.random.default_rng(int(scale * 1000) % 2**31)
    for n in (1, 2, 3, 4, 6):
        for _ in range(20):
            a = rng.standard_normal((n, n))
            a *= scale / np.linalg.norm(a, 1)
            # the conditioning of exp bounds any algorithm's agreement; 1e-12 is far above the roundoff here
            assert _rel(expm(a), scipy_expm(a)) < 1e-12 * max(1.0, scale), (n, scale)


def test_exact_cases():
    d = np.diag([-3.0, 0.5, 2.0])
    assert np.allclose(expm(d), np.diag(np.exp([-3.0, 0.5, 2.0])), rtol=1e-14, atol=0)
    w, t = 2 * np.pi * 33.0, 1.0 / 4096
    rot = expm(np.array([[0.0, -w * t], [w * t, 0.0]]))
    assert np.allclose(rot, [[np.cos(w * t), -np.sin(w * t)], [np.sin(w * t), np.cos(w * t)]], rtol=0, atol=1e-15)
    nil = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, 0.0]])     # an integrator chain: a polynomial
    assert np.allclose(expm(2.0 * nil), [[1, 2, 2], [0, 1, 2], [0, 0, 1]], rtol=0, atol=1e-15)
    assert expm(np.zeros((0, 0))).shape == (0, 0)


def test_group_property_on_a_stiff_augmented_zoh_matrix():
    """exp(2 M) = exp(M)^2 for the augmented matrix of a 4th-order instrument filter at 4096 Hz (what it serves)."""
    w = 2 * np.pi * np.array([33.0, 183.0])
    a = np.zeros((5, 5))
    a[:3, 1:4] = np.eye(3)
    poly = np.poly(np.concatenate([-0.02 * w + 1j * w, -0.02 * w - 1j * w])).real
    a[3, :4] = -poly[::-1][:4]
    a[3, 4] = 1.0
    m = a / 4096.0
    e = expm(m)
    assert _rel(expm(2 * m), e @ e) < 1e-12
    assert _rel(e, scipy_expm(m)) < 1e-12


def test_non_finite_and_wrong_shapes():
    assert np.all(np.isnan(expm(np.array([[np.nan, 0.0], [0.0, 1.0]]))))
    with pytest.raises(ValueError, match="square"):
        expm(np.zeros((2, 3)))
