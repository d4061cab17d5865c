"""Extended-precision reference of the ZOH discretization of a second-order mode (validation only).

``scripts/validate_zoh.py`` prints the error table, ``test/test_zoh.py`` checks it. Python's ``decimal`` at ``PREC``
digits from the float inputs taken exactly: ``Phi = e^{s h}[c I + S (M - s I)]`` (Putzer form, ``s = -a1/(2 a2)``, ``q^2
= s^2 - 1/a2``, ``c = cosh(q h)``, ``S = sinh(q h)/q``, trigonometric for ``q^2 < 0``), ``Gamma = [1 - Phi11, -Phi21]``;
at 90 digits nothing the float code resolves is lost to cancellation, and :func:`decimal_expm` (Taylor series with
scaling and squaring) checks the closed form independently. Error: ``|x - ref| / scale`` per entry, ``scale`` the larger
of ``|ref|`` and the size of the terms the exact value is made of in the dimensionless coordinates ``[w, h w']`` (for
complex poles their envelope); ``Gamma1`` relative to itself; scales below 1e-290 count as underflow.
"""

from __future__ import annotations

import decimal
from decimal import Decimal as Dec

import numpy as np

from ..core.estimation.zoh import second_order_zoh

PREC = 90


def _dec_pi() -> Dec:
    """pi to the current precision (decimal module recipe)."""
    decimal.getcontext().prec += 2
    three = Dec(3)
    lasts, t, s, n, na, d, da = Dec(0), three, Dec(3), 1, 0, 0, 24
    while s != lasts:
        lasts = s
        n, na = n + na, na + 8
        d, da = d + da, da + 32
        t = (t * n) / d
        s += t
    decimal.getcontext().prec -= 2
    return +s


def _cos_sinc(y: Dec, pi: Dec) -> tuple[Dec, Dec]:
    """``cos(y)`` and ``sin(y)/y`` by Taylor series (argument reduced mod 2 pi for the series of cos, sin)."""
    if y == 0:
        return Dec(1), Dec(1)
    two_pi = 2 * pi
    yr = y - two_pi * (y / two_pi).to_integral_value(rounding=decimal.ROUND_FLOOR)
    eps = Dec(10) ** (-(decimal.getcontext().prec + 5))
    c, s, term, k = Dec(1), Dec(0), Dec(1), 0
    s_term = yr
    s = yr
    while True:   # cos
        k += 2
        term = -term * yr * yr / (k * (k - 1))
        c += term
        if abs(term) < eps:
            break
    k = 1
    while True:   # sin
        k += 2
        s_term = -s_term * yr * yr / (k * (k - 1))
        s += s_term
        if abs(s_term) < eps:
            break
    return c, s / y


def _cosh_sinhc(x: Dec) -> tuple[Dec, Dec]:
    """``cosh(x)`` and ``sinh(x)/x`` (series for small x, exponentials otherwise)."""
    if x < 1:
        eps = Dec(10) ** (-(decimal.getcontext().prec + 5))
        c, s, tc, ts, k = Dec(1), Dec(1), Dec(1), Dec(1), 0
        while True:
            k += 2
            tc = tc * x * x / (k * (k - 1))
            ts = ts * x * x / (k * (k + 1))
            c += tc
            s += ts
            if tc < eps:
                return c, s
    ep, em = x.exp(), (-x).exp()
    return (ep + em) / 2, (ep - em) / (2 * x)


def reference_zoh(a1: float, a2: float, h: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Reference ``Phi, Gamma`` (as float, rounded from ``PREC`` digits) and the natural scale of each entry of
    ``[Phi | Gamma]`` (3x2 layout: rows of Phi then Gamma as a row)."""
    with decimal.localcontext() as ctx:
        ctx.prec = PREC
        ctx.Emin, ctx.Emax = -10**8, 10**8
        A1, A2, H = Dec(a1), Dec(a2), Dec(h)
        s = -A1 / (2 * A2)
        q2 = s * s - 1 / A2
        sig = s * H
        if q2 > 0 and q2.sqrt() * H >= 1:   # e^{s h} cosh, e^{s h} sinh/x from e^{(s +- q) h}: no huge exponents
            x = q2.sqrt() * H
            ep, em = ((H * H / A2) / (sig - x)).exp(), (sig - x).exp()   # sig + x = (h^2/a2)/(sig - x)
            ec, es = (ep + em) / 2, (ep - em) / (2 * x)
        else:
            if q2 > 0:
                c, sinc = _cosh_sinhc(q2.sqrt() * H)
            elif q2 < 0:
                c, sinc = _cos_sinc((-q2).sqrt() * H, _dec_pi())
            else:
                c, sinc = Dec(1), Dec(1)
            e = sig.exp()
            ec, es = e * c, e * sinc
        p11 = ec - sig * es
        p12 = es * H
        p21 = -p12 / A2
        p22 = ec + sig * es
        g1 = 1 - p11
        g2 = p12 / A2
        # natural scales in coordinates [w, h w']: Phi12/h, h Phi21, h Gamma2 dimensionless; an oscillating entry
        # (q^2 < 0) is measured against its envelope e^{s h} (1, 1/y), not its value near a zero of cos or sin
        if q2 < 0:
            y = (-q2).sqrt() * H
            env = e * (1 / y if y > 1 else Dec(1))
            sc_diag, sc_12 = e + abs(sig) * env, env * H
        else:
            sc_diag, sc_12 = abs(ec) + abs(sig * es), abs(es) * H
        sc_21 = sc_12 / A2
        vals = [p11, p12, p21, p22, g1, g2]
        scales = [sc_diag, sc_12, sc_21, sc_diag, abs(g1), sc_21]
        ref = np.array([float(v) for v in vals])
        scale = np.array([float(max(abs(v), sc)) for v, sc in zip(vals, scales, strict=True)])
    return ref[:4].reshape(2, 2), ref[4:], scale


def decimal_expm(a1: float, a2: float, h: float, prec: int = 60) -> tuple[np.ndarray, np.ndarray]:
    """``expm`` of the augmented matrix ``[[M h, B h], [0, 0]]`` in ``decimal``: Taylor series of the matrix
    scaled by ``2^-j`` (norm <= 1/2), then ``j`` squarings. Independent of the closed form; for moderate norms."""
    with decimal.localcontext() as ctx:
        ctx.prec = prec
        A1, A2, H = Dec(a1), Dec(a2), Dec(h)
        m = [[Dec(0), H, Dec(0)], [-H / A2, -A1 * H / A2, H / A2], [Dec(0), Dec(0), Dec(0)]]
        norm = max(sum((abs(v) for v in row), Dec(0)) for row in m)
        j = 0
        while norm > Dec("0.5"):
            norm /= 2
            j += 1
        f = Dec(2) ** j
        m = [[v / f for v in row] for row in m]

        def mul(x: list, y: list) -> list:
            return [[sum(x[i][k] * y[k][jj] for k in range(3)) for jj in range(3)] for i in range(3)]

        out = [[Dec(int(i == jj)) for jj in range(3)] for i in range(3)]
        term = [row[:] for row in out]
        eps = Dec(10) ** (-(prec + 5))
        for k in range(1, 200):
            term = [[v / k for v in row] for row in mul(term, m)]
            out = [[out[i][jj] + term[i][jj] for jj in range(3)] for i in range(3)]
            if max(abs(v) for row in term for v in row) < eps:
                break
        for _ in range(j):
            out = mul(out, out)
        e = np.array([[float(v) for v in row] for row in out])
    return e[:2, :2], e[:2, 2]


def sample_iterates(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Random admissible ``(a1, a2, h)``: log-uniform ``h/sqrt(a2)`` (1e-8 .. 1e4) and damping classes
    (undamped, light, critical +- 1e-12 .. 1e-3, overdamped, stiff up to ``q h = 1e4``, near-singular a2).
    Returns the (n, 3) array and the class index per row."""
    rng = np.random.default_rng(seed)
    out = np.empty((n, 3))
    cls = rng.integers(0, 6, n)
    for k in range(n):
        h = 10.0 ** rng.uniform(-6, 0)
        c = cls[k]
        if c == 4:   # stiff: slow pole from lambda1 h in 1e-4..30, fast pole q h up to 1e4; a2 -> 0
            lam1h = 10.0 ** rng.uniform(-4, 1.5)
            lam2h = lam1h * 10.0 ** rng.uniform(0.5, 8)
            lam2h = min(lam2h, 2e4)
            l1, l2 = lam1h / h, max(lam2h, lam1h * 1.01) / h
            a2 = 1.0 / (l1 * l2)
            a1 = (l1 + l2) * a2
        elif c == 5:  # near-singular a2 with a fixed first-order part: a2 = eps a1^2
            a1 = 10.0 ** rng.uniform(-4, 2) * h
            a2 = a1 * a1 * 10.0 ** rng.uniform(-12, -1)
        else:
            rho = 10.0 ** rng.uniform(-8, 4)          # omega h
            a2 = (h / rho) ** 2
            if c == 0:
                zeta = 0.0 if rng.random() < 0.2 else 10.0 ** rng.uniform(-4, -1)
            elif c == 1:
                zeta = rng.uniform(0.1, 0.99)
            elif c == 2:
                zeta = 1.0 + rng.choice([-1, 1]) * 10.0 ** rng.uniform(-12, -3) * (rng.random() > 0.1)
            else:
                zeta = 10.0 ** rng.uniform(0.0, 3.0)
            a1 = 2.0 * zeta * np.sqrt(a2)
        out[k] = (a1, a2, h)
    return out, cls


CLASS_NAMES = ("undamped/light", "moderate", "near-critical", "overdamped", "stiff", "near-singular a2")


def errors(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per point: max scaled error over the 6 entries, and whether every entry is finite."""
    err = np.empty(len(points))
    fin = np.empty(len(points), dtype=bool)
    phi, gam = np.zeros((2, 2)), np.zeros(2)
    for k, (a1, a2, h) in enumerate(points):
        second_order_zoh(a1, a2, h, phi, gam)
        ref_phi, ref_gam, scale = reference_zoh(a1, a2, h)
        x = np.concatenate((phi.ravel(), gam))
        ref = np.concatenate((ref_phi.ravel(), ref_gam))
        fin[k] = bool(np.all(np.isfinite(x)))
        tiny = scale < 1e-290
        e = np.abs(x - ref) / np.where(tiny, 1.0, scale)
        e[tiny] = np.abs(x - ref)[tiny] / 1e-290 * 1e-16
        err[k] = float(np.max(e))
    return err, fin
