"""Quantiles of the F distribution without ``scipy.special``, whose import costs about 0.15 s at the start of every
tool and of the node (the diagnosis needs one quantile per offline fit, :func:`.offline.initial_transient_test`).

``F(d1, d2)`` is a transformed beta variable: with ``y = d2 / (d2 + d1 F)``, ``P(F > f) = I_y(d2/2, d1/2)``, the
regularized incomplete beta function (Abramowitz & Stegun 26.6.2). It is evaluated by its continued fraction
(A&S 26.5.8, modified Lentz) and inverted by Newton's method inside a bisection bracket, to about 1e-12 relative
(test/test_distributions.py compares with ``scipy.special.fdtri``).
"""

from __future__ import annotations

import math
from functools import lru_cache

_TINY = 1e-300
_EPS = 1e-15
_MAX_TERMS = 100_000


def _beta_continued_fraction(x: float, a: float, b: float) -> float:
    """The continued fraction of ``I_x(a, b)`` (A&S 26.5.8), converging fast for ``x < (a + 1) / (a + b + 2)``."""
    qab, qap, qam = a + b, a + 1.0, a - 1.0
    c, d = 1.0, 1.0 - qab * x / qap
    d = 1.0 / (d if abs(d) > _TINY else _TINY)
    h = d
    for m in range(1, _MAX_TERMS):
        m2 = 2 * m
        for aa in (m * (b - m) * x / ((qam + m2) * (a + m2)), -(a + m) * (qab + m) * x / ((a + m2) * (qap + m2))):
            d = 1.0 + aa * d
            d = 1.0 / (d if abs(d) > _TINY else _TINY)
            c = 1.0 + aa / c
            c = c if abs(c) > _TINY else _TINY
            h *= d * c
        if abs(d * c - 1.0) < _EPS:
            return h
    raise ArithmeticError(f"incomplete beta continued fraction did not converge (x={x}, a={a}, b={b})")


def regularized_beta(x: float, a: float, b: float) -> float:
    """``I_x(a, b)``, the regularized incomplete beta function (A&S 26.5.1), ``a, b > 0``."""
    if not (a > 0.0 and b > 0.0) or math.isnan(x):
        raise ValueError(f"regularized_beta needs a, b > 0 and a number x, got x={x}, a={a}, b={b}")
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    log_front = (math.lgamma(a + b) - math.lgamma(a) - math.lgamma(b) + a * math.log(x) + b * math.log1p(-x))
    if x < (a + 1.0) / (a + b + 2.0):
        return math.exp(log_front) * _beta_continued_fraction(x, a, b) / a
    return 1.0 - math.exp(log_front) * _beta_continued_fraction(1.0 - x, b, a) / b


def _inverse_regularized_beta(q: float, a: float, b: float) -> float:
    """The ``y`` in (0, 1) with ``I_y(a, b) = q``: Newton on ``I_y - q`` (derivative the beta density), kept inside
    a bisection bracket so that it cannot leave (0, 1) or cycle."""
    lo, hi = 0.0, 1.0
    log_norm = math.lgamma(a + b) - math.lgamma(a) - math.lgamma(b)
    y = a / (a + b)                                   # the mean: a start inside the bulk
    for _ in range(400):
        g = regularized_beta(y, a, b) - q
        if g == 0.0:
            return y
        if g > 0.0:
            hi = y
        else:
            lo = y
        dens = math.exp(log_norm + (a - 1.0) * math.log(y) + (b - 1.0) * math.log1p(-y))
        step = g / dens if dens > 0.0 and math.isfinite(dens) else math.inf
        nxt = y - step
        if not lo < nxt < hi:
            nxt = 0.5 * (lo + hi)
        if abs(nxt - y) <= 4.0 * _EPS * y:
            return nxt
        y = nxt
    return y


@lru_cache(maxsize=256)
def f_quantile(d1: float, d2: float, p: float) -> float:
    """The ``p`` quantile of ``F(d1, d2)`` (``scipy.special.fdtri(d1, d2, p)``), ``0 < p < 1``, ``d1, d2 > 0``.
    Solved in the nearer tail, which keeps the precision of a small probability: the upper one
    ``P(F > f) = 1 - p = I_y(d2/2, d1/2)`` with ``y = d2 / (d2 + d1 f)``, the lower one ``P(F <= f) = p =
    I_x(d1/2, d2/2)`` with ``x = d1 f / (d1 f + d2)``."""
    if not (0.0 < p < 1.0) or not (d1 > 0.0 and d2 > 0.0):
        raise ValueError(f"f_quantile needs 0 < p < 1 and d1, d2 > 0, got d1={d1}, d2={d2}, p={p}")
    if p >= 0.5:
        y = _inverse_regularized_beta(1.0 - p, 0.5 * d2, 0.5 * d1)
        return d2 * (1.0 - y) / (d1 * y)
    x = _inverse_regularized_beta(p, 0.5 * d1, 0.5 * d2)
    return d2 * x / (d1 * (1.0 - x))
