"""Exact zero-order-hold discretization of the small state-variable filters (numba-compiled).

Every filter of the SRIVC family is built from ``a2 w'' + a1 w' + w = v(t)``, ``v`` held on ``[t_k, t_k + h)``
([RA-SRIVC] eqs. 26-28), in physical coordinates ``x = [w, w']``: ``x_{k+1} = Phi x_k + Gamma v_k``, outputs ``1/A v =
w``, ``p/A v = w'``, ``p^2/A v = (v_k - w - a1 w') / a2``. Physical coordinates keep the state meaningful when the
coefficients change (Remark 4.4). ZOH-exact because Tustin prefilters biased the closed-loop estimates by 1-4 stds. For
``a1 >= 0, a2 > 0`` (every iterate after the projection of §4.7) :func:`second_order_zoh` is exact and finite for any
``h > 0``, by regime of the poles: power series of the divided differences of ``exp`` for small ``|lambda h|``; ``expm(M
h) = e^{s h} [c I + S (M - s I)]`` (``s = tr(M)/2``, ``c = cos/cosh(q h)``, ``S = sin/sinh(q h)/q``) when underdamped or
mildly overdamped; else the real-pole form with ``e^{lambda h} <= 1`` only. ``Gamma = [1 - Phi_11, -Phi_21]``.
``scripts/validate_zoh.py`` measures the error against a 90-digit reference.
"""

from __future__ import annotations

import math

import numpy as np

from .compiled import kernel

_INV_FACT = np.array([1.0 / math.factorial(k) for k in range(40)])   # 1/k! (compile-time constants in numba)
_INV_INT = np.array([1.0 / k if k else 0.0 for k in range(40)])
SERIES_RADIUS = 1.0  # |pole| h below which Phi, Gamma come from the divided-difference series (all terms small)
POLE_FORM_X = 0.5   # overdamped: q h from which the real-pole form replaces cosh/sinh (no e^{+q h} anywhere)
ZohCoefficients = tuple[float, float, float, float, float, float]   # Phi11, Phi12, Phi21, Phi22, Gamma1, Gamma2


@kernel(inline=True)
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


@kernel(inline=True)
def _general_zoh(a1: float, a2: float, h: float) -> ZohCoefficients:
    """``e^{s h}[c I + S (M - s I)]`` for any coefficients with ``a2 != 0`` (used outside the admissible set)."""
    s = -0.5 * a1 / a2
    q2 = s * s - 1.0 / a2
    c, sv, one_minus_c = _c_s_1mc(q2, h)
    e = math.exp(s * h)
    em1 = math.expm1(s * h)
    # Gamma1 = 1 - e (c - s S) = (1 - c) + s S - em1 (c - s S)
    return (e * (c - s * sv), e * sv, -e * sv / a2, e * (c + s * sv),
            one_minus_c + s * sv - em1 * (c - s * sv), e * sv / a2)


@kernel(inline=True)
def _discriminant(a1: float, a2: float) -> float:
    """``a1^2 - 4 a2`` with the rounding error of ``a1^2`` added back (Dekker's exact product).

    ``a1^2 - 4 a2`` is exact by Sterbenz' lemma where the two nearly cancel (near-critical damping), so the
    result keeps full relative precision there; the damping ratio is not rounded away.
    """
    p = a1 * a1
    if not (1e-290 < p < 1e290):
        return p - 4.0 * a2
    big = 134217729.0 * a1
    hi = big - (big - a1)
    lo = a1 - hi
    err = ((hi * hi - p) + 2.0 * hi * lo) + lo * lo
    return (p - 4.0 * a2) + err


@kernel(inline=True)
def _series_zoh(e1: float, e2: float, rho: float, h: float, a2: float) -> ZohCoefficients:
    """All poles small (``|lambda| h <= SERIES_RADIUS``): divided differences of ``exp`` as power series.

    With ``z1, z2 = lambda_{1,2} h`` (``e1 = z1 + z2 = 2 s h``, ``e2 = z1 z2 = h^2/a2``, real also for complex
    poles), ``d1 = exp[z1, z2] = sum_k h_k/(k+1)!`` and ``d2 = exp[0, z1, z2] = sum_k h_k/(k+2)!`` with the
    complete symmetric polynomials ``h_k = e1 h_{k-1} - e2 h_{k-2}``; then ``Phi12 = h d1``, ``Gamma1 = e2 d2``
    (the step response, full relative precision however small h is), ``Phi11 = 1 - Gamma1``,
    ``Phi22 = 1 + e1 d1 - e2 d2``, ``Gamma2 = -Phi21 = Phi12/a2``.
    """
    hm2 = 1.0
    hm1 = e1
    d1 = 1.0 + e1 * 0.5
    d2 = 0.5 + e1 * _INV_FACT[3]
    bound = rho        # rho^k / k! >= |h_k|/(k+1)! (|h_k| <= (k+1) rho^k)
    for k in range(2, 34):
        hk = e1 * hm1 - e2 * hm2
        d1 += hk * _INV_FACT[k + 1]
        d2 += hk * _INV_FACT[k + 2]
        hm2 = hm1
        hm1 = hk
        bound *= rho * _INV_INT[k]
        if bound < 1e-18:
            break
    g1 = e2 * d2
    g2 = (h / a2) * d1
    return 1.0 - g1, h * d1, -g2, 1.0 + e1 * d1 - g1, g1, g2


@kernel(inline=True)
def _oscillatory_zoh(x2: float, sigma: float, disc: float, h: float, a2: float) -> ZohCoefficients:
    """Underdamped (``x2 = q^2 h^2 < 0``) or overdamped with small ``q h``: ``e^{s h}[c I + S (M - s I)]``.

    ``c = cos/cosh``, ``St = sin(x)/x`` or ``sinh(x)/x`` are bounded here, ``e^{sigma}`` with ``sigma = s h <= 0``
    never overflows. ``Gamma1 = 1 - Phi11`` where ``Phi11 <= 1/2``; otherwise the expm1/half-angle form.
    """
    if abs(x2) < 1e-2:
        omc = -(x2 / 2.0) * (1.0 + x2 / 12.0 * (1.0 + x2 / 30.0 * (1.0 + x2 / 56.0 * (1.0 + x2 / 90.0))))
        st = 1.0 + x2 / 6.0 * (1.0 + x2 / 20.0 * (1.0 + x2 / 42.0 * (1.0 + x2 / 72.0)))
        c = 1.0 - omc
    elif x2 > 0.0:
        x = math.sqrt(x2)
        half = math.sinh(0.5 * x)
        c = math.cosh(x)
        st = math.sinh(x) / x
        omc = -2.0 * half * half
    else:
        x = math.sqrt(-x2)
        half = math.sin(0.5 * x)
        c = math.cos(x)
        st = math.sin(x) / x
        omc = 2.0 * half * half
    e = math.exp(sigma)
    hoa2 = h / a2
    if math.isfinite(hoa2):
        g2 = e * st * hoa2
    else:  # h/a2 = 2 x / sqrt|disc|: only reached with a2 near the underflow limit
        g2 = e * st * 2.0 * math.sqrt(abs(x2)) / math.sqrt(abs(disc)) if e > 0.0 else 0.0
    p11 = e * (c - sigma * st)
    if p11 < 0.5:
        g1 = 1.0 - p11
    else:
        g1 = omc + sigma * st - math.expm1(sigma) * (c - sigma * st)
    return p11, e * st * h, -g2, e * (c + sigma * st), g1, g2


@kernel(inline=True)
def _real_pole_zoh(a1: float, a2: float, disc: float, h: float) -> ZohCoefficients:
    """Overdamped, ``q h >= POLE_FORM_X``: real poles ``lambda_1 = -2/(a1 + sD)`` (slow) and
    ``lambda_2 = -(a1 + sD)/(2 a2)`` (fast), ``sD = sqrt(a1^2 - 4 a2)``; only ``e^{lambda h} <= 1`` appear.

    ``E1 = e^{lambda_1 h}``, ``g = 1 - e^{-(lambda_1 - lambda_2) h}`` (expm1): ``Gamma2 = E1 g/sD``,
    ``Phi12 = a2 Gamma2``, ``Phi11 = E1 - lambda_1 Phi12`` (a sum of positive terms), ``Phi22 = E1 + lambda_2 Phi12``,
    ``Gamma1 = 1 - Phi11`` or, where ``Phi11 > 1/2``, ``(lambda_2 (E1 - 1) - lambda_1 (E2 - 1))/(lambda_1 -
    lambda_2)``. A very stiff fast pole gives ``e^{lambda_2 h} = 0`` gracefully (first-order limit).
    """
    sd = math.sqrt(disc)
    den = a1 + sd
    lam1 = -2.0 / den
    z1 = lam1 * h
    e1 = math.exp(z1)
    g = -math.expm1(-sd * (h / a2))
    g2 = e1 * g / sd
    p12 = a2 * g2
    p11 = e1 - lam1 * p12
    if p11 < 0.5:
        g1 = 1.0 - p11
    else:
        z2 = -(den / (2.0 * a2)) * h
        g1 = (-(0.5 * den) * math.expm1(z1) + (2.0 * a2 / den) * math.expm1(z2)) / sd
    return p11, p12, -g2, e1 * (1.0 - den * g / (2.0 * sd)), g1, g2


@kernel(inline=True)
def zoh_coefficients(a1: float, a2: float, h: float) -> ZohCoefficients:
    """The exact ZOH of ``a2 w'' + a1 w' + w = v`` as ``(Phi11, Phi12, Phi21, Phi22, Gamma1, Gamma2)``.

    Admissible coefficients (``a1 >= 0``, ``a2 > 0``, every iterate after the projection of [RA-SRIVC] §4.7): finite
    and accurate to a few ulp of each entry's scale for any ``h > 0`` (``scripts/validate_zoh.py``), by regime of
    the poles ``lambda`` of ``1/A``: all ``|lambda| h <= SERIES_RADIUS``: divided-difference series;
    underdamped or ``q h < POLE_FORM_X``: ``e^{s h}`` times bounded cos/cosh terms; otherwise the real-pole form
    (no ``e^{+q h}``). Other non-zero ``a2`` (unstable, not admissible) use the plain closed form; ``a2 = 0`` or
    non-finite inputs give NaN entries (no discretization exists; callers reject them). Scalars in and out: the
    per-sample kernel calls it without touching an array (no reference counting in its loop).
    """
    if not (a1 >= 0.0 and a2 > 0.0 and h > 0.0):
        if a2 != 0.0 and math.isfinite(a1) and math.isfinite(a2) and math.isfinite(h):
            return _general_zoh(a1, a2, h)
        nan = math.nan   # no discretization (a2 = 0, NaN): NaN entries, which the kernel rejects and counts
        return nan, nan, nan, nan, nan, nan
    disc = _discriminant(a1, a2)            # 4 a2^2 q^2
    t = h / (2.0 * a2)
    sigma = -a1 * t                         # s h
    x2 = disc * t * t if math.isfinite(t) else (math.inf if disc > 0.0 else -math.inf)
    if disc < 0.0:
        rho = h / math.sqrt(a2)             # |z1| = |z2| for complex poles
    else:
        rho = (a1 + math.sqrt(disc)) * t    # |lambda_2| h, the fast pole
    if rho <= SERIES_RADIUS:
        return _series_zoh(2.0 * sigma, h * (h / a2), rho, h, a2)
    if disc < 0.0 or x2 < POLE_FORM_X * POLE_FORM_X:
        return _oscillatory_zoh(x2, sigma, disc, h, a2)
    return _real_pole_zoh(a1, a2, disc, h)


@kernel
def second_order_zoh(a1: float, a2: float, h: float, phi: np.ndarray, gamma: np.ndarray) -> None:
    """Fill ``phi`` (2x2) and ``gamma`` (2,) with :func:`zoh_coefficients` (the exact ZOH of ``a2 w'' + a1 w' + w =
    v``)."""
    phi[0, 0], phi[0, 1], phi[1, 0], phi[1, 1], gamma[0], gamma[1] = zoh_coefficients(a1, a2, h)


@kernel
def integrator_chain_zoh(l: int, h: float, phi: np.ndarray, gamma: np.ndarray) -> None:
    """Exact ZOH of ``1/p^l`` in coordinates ``[w, w', ..., w^(l-1)]``: ``Phi_ij = h^(j-i)/(j-i)!``."""
    for i in range(l):
        for j in range(l):
            phi[i, j] = h ** (j - i) / math.gamma(j - i + 1.0) if j >= i else 0.0
        gamma[i] = h ** (l - i) / math.gamma(l - i + 1.0)


def _scaled_companion_zoh(a: np.ndarray, b: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray] | None:
    """``x' = [[0, s], [alpha, beta]] x + [0, g] v`` (the scaled companion form of ``core.filters.svf_continuous``)
    with an admissible ``1/A``: exact :func:`second_order_zoh` in ``[w, w']`` coordinates, ``x = diag(1, 1/s)
    [w, w']``; ``None`` for any other system."""
    sc = a[0, 1]
    if not (a[0, 0] == 0.0 and sc > 0.0 and b[0, 0] == 0.0 and np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        return None
    k = -sc * a[1, 0]          # w'' = -k w - c w' + s g v
    c = -a[1, 1]
    if not (k > 0.0 and c >= 0.0 and math.isfinite(1.0 / k)):
        return None
    a2 = 1.0 / k
    phi, gam = np.zeros((2, 2)), np.zeros(2)
    second_order_zoh(c * a2, a2, h, phi, gam)
    gain = sc * b[1, 0] * a2
    phi[0, 1] *= sc
    phi[1, 0] /= sc
    return phi, np.array([[gam[0] * gain], [gam[1] * gain / sc]])


def zoh_matrices(a: np.ndarray, b: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact ZOH of ``x' = a x + b v``: second-order (scaled) companion forms with an admissible ``1/A`` by
    :func:`second_order_zoh` (finite and accurate however stiff), any other system by the augmented matrix
    exponential (``scipy.linalg.expm``, imported on the first such system)."""
    from scipy.linalg import expm

    a = np.atleast_2d(np.asarray(a, dtype=float))
    b = np.asarray(b, dtype=float).reshape(a.shape[0], -1)
    n, m = b.shape
    if n == 2 and m == 1 and h > 0.0:
        exact = _scaled_companion_zoh(a, b, h)
        if exact is not None:
            return exact
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
