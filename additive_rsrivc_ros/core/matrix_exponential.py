"""The matrix exponential without ``scipy.linalg``, whose import costs about 0.17 s at the start of every tool and of
the node (:func:`.zoh.zoh_matrices` needs it for the offline filters of order above two).

Scaling and squaring with a diagonal Pade approximant of degree 3, 5, 7, 9 or 13 (Al-Mohy & Higham, "A new scaling
and squaring algorithm for the matrix exponential", SIAM J. Matrix Anal. Appl. 31(3), 2009, Algorithm 5.1, the
algorithm of ``scipy.linalg.expm``): the degree and the number of squarings are chosen from ``||A^k||^(1/k)``
instead of ``||A||`` (no overscaling of a non-normal matrix, such as a filter cascade with a large gain), plus the
correction ``ell`` that bounds the backward error by the unit roundoff. The matrices here are at most a few
states, so every norm is computed exactly. test/test_matrix_exponential.py compares it with ``scipy.linalg.expm``
and with exact exponentials.
"""

from __future__ import annotations

import math

import numpy as np

# theta_m of Al-Mohy & Higham (2009) Table 3.1: the largest ||A^k||^(1/k) for which the degree-m Pade approximant is
# exact to the unit roundoff (double precision); 4.25 for m = 13 (their eq. 5.1 and Algorithm 5.1)
_THETA = {3: 1.495585217958292e-2, 5: 2.539398330063230e-1, 7: 9.504178996162932e-1, 9: 2.097847961257068e0,
          13: 4.25}
# 1 / |c_(2m+1)|: the leading coefficient of the backward-error series of the degree-m approximant (Higham 2005,
# eqs. 2.2 and 2.6), for ell (Al-Mohy & Higham 2009, eq. 5.3)
_ELL_C = {3: 100800.0, 5: 10059033600.0, 7: 4487938430976000.0, 9: 5.914384781877412e21, 13: 1.1325077560602111e35}
_UNIT_ROUNDOFF = 2.0 ** -53

# numerator coefficients b_0..b_m of the degree-m Pade approximant of exp (Higham 2005, eq. 2.2 and Algorithm 2.3)
_PADE = {
    3: (120.0, 60.0, 12.0, 1.0),
    5: (30240.0, 15120.0, 3360.0, 420.0, 30.0, 1.0),
    7: (17297280.0, 8648640.0, 1995840.0, 277200.0, 25200.0, 1512.0, 56.0, 1.0),
    9: (17643225600.0, 8821612800.0, 2075673600.0, 302702400.0, 30270240.0, 2162160.0, 110880.0, 3960.0, 90.0,
        1.0),
    13: (64764752532480000.0, 32382376266240000.0, 7771770303897600.0, 1187353796428800.0, 129060195264000.0,
         10559470521600.0, 670442572800.0, 33522128640.0, 1323241920.0, 40840800.0, 960960.0, 16380.0, 182.0, 1.0),
}


def _norm1(a: np.ndarray) -> float:
    return float(np.max(np.sum(np.abs(a), axis=0)))


def _ell(a: np.ndarray, m: int) -> int:
    """Extra squarings that bound the backward error of the degree-``m`` approximant by the unit roundoff (Al-Mohy
    & Higham 2009, eq. 5.3): ``max(ceil(log2(alpha / u) / (2 m)), 0)``, ``alpha = |c| || |A|^(2m+1) || / ||A||``."""
    v = np.ones(a.shape[0])
    mt = np.abs(a).T
    for _ in range(2 * m + 1):
        v = mt @ v                  # || |A|^p ||_1 of a non-negative matrix: the largest column sum
    power_norm = float(np.max(v))
    if power_norm == 0.0 or not math.isfinite(power_norm):
        return 0
    alpha = power_norm / (_norm1(a) * _ELL_C[m])
    return max(int(math.ceil(math.log2(alpha / _UNIT_ROUNDOFF) / (2 * m))), 0)


def _pade_low(a: np.ndarray, even: tuple[np.ndarray, np.ndarray, np.ndarray], m: int) -> tuple[np.ndarray,
                                                                                                np.ndarray]:
    """``(U, V)`` of the degree-``m`` approximant, ``m`` in 3..9, from the powers ``even = (A^2, A^4, A^6)`` the
    degree choice computed (``A^8 = A^6 A^2`` for ``m = 9``): ``U`` the odd part, ``V`` the even part."""
    b = _PADE[m]
    powers = [np.eye(a.shape[0]), *even][:(m + 1) // 2]
    if m == 9:
        powers.append(even[2] @ even[0])
    u = sum((b[2 * k + 1] * p for k, p in enumerate(powers)), np.zeros_like(a))
    v = sum((b[2 * k] * p for k, p in enumerate(powers)), np.zeros_like(a))
    return a @ u, v


def _pade13(a: np.ndarray, powers: tuple[np.ndarray, np.ndarray, np.ndarray], s: int) -> tuple[np.ndarray,
                                                                                                    np.ndarray]:
    """``(U, V)`` of the degree-13 approximant of ``2^-s A`` from the powers ``A^2, A^4, A^6`` (Higham 2005's
    evaluation scheme, six matrix products)."""
    b = _PADE[13]
    ident = np.eye(a.shape[0])
    a1, a2, a4, a6 = a * 2.0 ** -s, powers[0] * 2.0 ** (-2 * s), powers[1] * 2.0 ** (-4 * s), \
        powers[2] * 2.0 ** (-6 * s)
    u = a1 @ (a6 @ (b[13] * a6 + b[11] * a4 + b[9] * a2) + b[7] * a6 + b[5] * a4 + b[3] * a2 + b[1] * ident)
    v = a6 @ (b[12] * a6 + b[10] * a4 + b[8] * a2) + b[6] * a6 + b[4] * a4 + b[2] * a2 + b[0] * ident
    return u, v


def expm(a: np.ndarray) -> np.ndarray:
    """``exp(a)`` of a square real matrix (Al-Mohy & Higham 2009, Algorithm 5.1, exact norms). Non-finite entries
    give a non-finite result, never an exception."""
    a = np.asarray(a, dtype=float)
    if a.ndim != 2 or a.shape[0] != a.shape[1]:
        raise ValueError(f"expm needs a square matrix, got shape {a.shape}")
    if a.size == 0:
        return np.zeros_like(a)
    if not np.all(np.isfinite(a)):
        return np.full_like(a, np.nan)
    with np.errstate(over="ignore", invalid="ignore"):     # an overflowing exponential is returned, not warned
        return _scaling_and_squaring(a)


def _scaling_and_squaring(a: np.ndarray) -> np.ndarray:
    """Al-Mohy & Higham (2009) Algorithm 5.1 on a finite square matrix."""
    if a.shape == (1, 1):
        return np.exp(a)
    a2 = a @ a
    a4 = a2 @ a2
    a6 = a4 @ a2
    d4, d6 = _norm1(a4) ** 0.25, _norm1(a6) ** (1.0 / 6.0)
    eta = max(d4, d6)
    for m in (3, 5):
        if eta < _THETA[m] and _ell(a, m) == 0:
            return _solve(*_pade_low(a, (a2, a4, a6), m))
    a8 = a4 @ a4
    d8 = _norm1(a8) ** 0.125
    eta3 = max(d6, d8)
    for m in (7, 9):
        if eta3 < _THETA[m] and _ell(a, m) == 0:
            return _solve(*_pade_low(a, (a2, a4, a6), m))
    eta5 = min(eta3, max(d8, _norm1(a8 @ a2) ** 0.1))
    if not math.isfinite(eta5):           # the powers overflow: scale by the norm itself (Higham 2005)
        eta5 = _norm1(a)
    s = max(int(math.ceil(math.log2(eta5 / _THETA[13]))), 0) if eta5 > 0.0 else 0
    s += _ell(a * 2.0 ** -s, 13)
    r = _solve(*_pade13(a, (a2, a4, a6), s))
    for _ in range(s):
        r = r @ r
    return r


def _solve(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``r_m = q_m^-1 p_m`` with ``p_m = V + U``, ``q_m = V - U``."""
    return np.linalg.solve(v - u, v + u)
