"""The F quantile and the incomplete beta function of :mod:`core.distributions` against scipy.special (the
reference the diagnosis used before; the module exists to spare its import)."""

import math

import numpy as np
import pytest
from scipy.special import betainc, fdtri

from additive_rsrivc_ros.core.distributions import f_quantile, regularized_beta


def test_regularized_beta_matches_scipy():
    rng = np.random.default_rng(7)
    for _ in range(500):
        a, b = np.exp(rng.uniform(-2.0, 8.0, 2))
        x = float(rng.uniform())
        assert regularized_beta(x, a, b) == pytest.approx(betainc(a, b, x), rel=1e-10, abs=1e-13)
    assert regularized_beta(0.0, 2.0, 3.0) == 0.0 and regularized_beta(1.0, 2.0, 3.0) == 1.0


@pytest.mark.parametrize("p", [1e-6, 1e-3, 0.1, 0.5, 0.9, 0.99, 0.999, 1 - 1e-4, 1 - 1e-6])
def test_f_quantile_matches_scipy_fdtri_in_both_tails(p):
    for d1 in (0.5, 1, 2, 3, 4, 6, 8, 12, 20):
        for m in (1, 2, 5, 20, 100, 1000, 5000):
            d2 = d1 * m
            assert f_quantile(float(d1), float(d2), p) == pytest.approx(fdtri(d1, d2, p), rel=1e-9), (d1, d2)


def test_f_quantile_is_a_quantile():
    """What it is, not what scipy says: the probability below the quantile is p."""
    for d1, d2, p in [(2.0, 40.0, 0.999), (4.0, 12.0, 0.05), (1.0, 1.0, 0.5)]:
        f = f_quantile(d1, d2, p)
        assert regularized_beta(d1 * f / (d1 * f + d2), d1 / 2, d2 / 2) == pytest.approx(p, rel=1e-12)
    assert f_quantile(1.0, 1.0, 0.5) == pytest.approx(1.0, rel=1e-12)     # F(d, d) has median 1


@pytest.mark.parametrize("args", [(0.0, 2.0, 0.5), (2.0, -1.0, 0.5), (2.0, 2.0, 0.0), (2.0, 2.0, 1.0),
                                  (2.0, 2.0, math.nan)])
def test_f_quantile_refuses_what_has_no_quantile(args):
    with pytest.raises(ValueError, match="f_quantile needs"):
        f_quantile(*args)
