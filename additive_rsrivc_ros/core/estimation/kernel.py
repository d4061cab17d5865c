"""Compiled per-sample kernel of the recursive additive SRIVC / CLSRIVC estimator ([RA-SRIVC] Algorithm 2).

Per mode four filter banks share the ZOH discretization of ``1/A_i(p)`` (:func:`.zoh.second_order_zoh`, eqs.
26-28, 33-35): Y on the residual output ``y~_i = y - sum_{j != i} x^_j``, U on the delayed input (regressor and the
simulated output ``x_i = b0/A u``, eq. 22), Z on the instrument input (closed loop ``z = S_uo(q, t_k) r`` from the
current model's noise-free loop, eq. 33), X on the auxiliary output ``b0 w_z`` (eq. 28). Filter states are physical
``[w, w']``, carried across coefficient changes (Remark 4.4); within a sample modes ``j < i`` are already updated and
the ``t_{k-1}`` states are replaced only after every mode (docs/DESIGN.md "Conventions"). IV-RLS (lines 7-9, B.5-B.7,
erratum 2 in docs/DESIGN.md): ``K = P phi^ / (lam + phi^T P phi^)``, ``P = (P_bar - K phi^T P_bar) / lam``; the
sandwich accumulator ``S = lam^2 S + zeta zeta^T`` gives the covariance ``sigma^2 P_bar S P_bar^T``. A rigid body's
free response ``c0 + c1 t`` is estimated with ``b0`` and folded into its input filter (:func:`fold_free_response`).
Every safeguard is counted, never silent: rejected updates per mode and reason (``rejr``), skipped samples, re-primes,
P capped at ``p_cap`` x P(0). All state lives in flat arrays (``core/estimation/recursive_state.py``), so a snapshot is
bit-identical; with ``NUMBA_DISABLE_JIT=1`` the same code runs interpreted.
"""

from __future__ import annotations

import math

import numpy as np

from .compiled import kernel
from .zoh import integrator_chain_zoh, second_order_zoh, zoh_coefficients

# bank indices
BY, BU, BZ, BX = 0, 1, 2, 3
N_BANKS = 4
NT = 3  # padded parameter length (second-order mode [a1, a2, b0]; rigid body uses [b0] in slot 0)

# int state slots (ist)
I_POS, I_SAMPLES, I_SUBCOUNT, I_HOLD, I_UPDATES, I_SKIPPED, I_REPRIMES, I_HELD, I_CAPPED, I_NONFINITE_Z = range(10)
N_IST = 10
# reasons of a rejected update (rejr columns): discretization, IV denominator, non-finite / a2 = 0 / max_step
R_DISC, R_DEN, R_STEP = range(3)
N_REJ = 3
# relative floor of the IV denominator: den = lam + phi^T P phi^ >= DEN_FLOOR lam (RLS: den >= lam), and den above
# DEN_ROUNDOFF times the sum of the magnitudes of its terms (below that its sign and size are round-off)
DEN_FLOOR = 1e-3
DEN_ROUNDOFF = 1e-12
# P(0) of a rigid body's free response (offset c0, slope c1 in 1/s): the weight of one sample, so the first samples
# determine it (its P then settles at about 1 - lam)
P0_FREE = 1.0
# float state slots (fst)
F_SIGACC, F_SIGW, F_RLAST, F_ULAST, F_YHAT = range(5)
N_FST = 5
# int config slots (cfg_i)
C_K, C_DELAY, C_SWEEPS, C_REFINE, C_PROJ, C_SUBSAMPLE, C_CLOSED, C_HOLDLEN = range(8)
N_CFGI = 8
# float config slots (cfg_f)
C_H, C_LAMSIG, C_MAXSTEP, C_PCAP = range(4)
N_CFGF = 4


@kernel
def project_second_order(a1: float, a2: float) -> tuple[float, float, bool]:
    """Reflect right-half-plane roots of ``A(p) = 1 + a1 p + a2 p^2`` into the LHP ([RA-SRIVC] §4.7).

    ``a2 > 0, a1 < 0``: both roots in the RHP, reflection maps ``a1 -> -a1``. ``a2 < 0``: real roots of
    opposite sign ``r- < 0 < r+``; reflecting ``r+`` gives ``a2 -> -a2`` and
    ``a1 -> 1/|r-| + 1/r+ = sqrt(a1^2 + 4|a2|)``. Returns ``(a1, a2, projected)``.
    """
    if a2 > 0.0:
        if a1 < 0.0:
            return -a1, a2, True
        return a1, a2, False
    if a2 < 0.0:
        return math.sqrt(a1 * a1 - 4.0 * a2), -a2, True
    return a1, a2, False


@kernel
def discretize_mode(kind: int, a1: float, a2: float, h: float, phi: np.ndarray, gam: np.ndarray) -> None:
    """``Phi, Gamma`` of ``1/A(p)`` (kind 0, closed form) or of ``1/p^kind`` (rigid body, [RA-SRIVC] §4.6)."""
    if kind == 0:
        second_order_zoh(a1, a2, h, phi, gam)
    else:
        phi[:, :] = 0.0
        gam[:] = 0.0
        integrator_chain_zoh(kind, h, phi[:kind, :kind], gam[:kind])


@kernel(inline=True)
def iv_denominator_ok(den: float, den_abs: float, lam: float) -> bool:
    """IV-RLS denominator ``den = lam + phi^T P phi^`` usable ([RA-SRIVC] eq. 31 / B.5): ``den >= DEN_FLOOR lam``
    (ordinary RLS has ``den >= lam``; a smaller one multiplies the step by ``lam/den``) and ``den >= DEN_ROUNDOFF
    den_abs`` (``den_abs = lam + sum |phi_a P_ac phi^_c|``: below that its value is round-off), all finite."""
    return math.isfinite(den) and math.isfinite(den_abs) and den >= DEN_FLOOR * lam and den >= DEN_ROUNDOFF * den_abs


@kernel(inline=True)
def _finite_coefficients(p00: float, p01: float, p10: float, p11: float, g0: float, g1: float) -> bool:
    """All of a mode's ``Phi`` (2x2) and ``Gamma`` (2,) entries are finite."""
    return (math.isfinite(p00) and math.isfinite(p01) and math.isfinite(p10) and math.isfinite(p11)
            and math.isfinite(g0) and math.isfinite(g1))


@kernel
def _finite_zoh(phi: np.ndarray, gam: np.ndarray) -> bool:
    """All entries of a mode's ``Phi`` (2x2) and ``Gamma`` (2,) are finite."""
    return _finite_coefficients(phi[0, 0], phi[0, 1], phi[1, 0], phi[1, 1], gam[0], gam[1])


@kernel
def _ensure_finite_zoh(i: int, kind: np.ndarray, theta: np.ndarray, thf: np.ndarray, h: float, phi: np.ndarray,
                       gam: np.ndarray) -> bool:
    """Cached ``Phi_i, Gamma_i`` finite; if not, re-discretized from the filter model, else from the estimate (which
    then becomes the filter model). False if neither has a finite discretization."""
    if _finite_zoh(phi[i], gam[i]):
        return True
    discretize_mode(kind[i], thf[i, 0], thf[i, 1], h, phi[i], gam[i])
    if _finite_zoh(phi[i], gam[i]):
        return True
    discretize_mode(kind[i], theta[i, 0], theta[i, 1], h, phi[i], gam[i])
    if _finite_zoh(phi[i], gam[i]):
        thf[i, 0] = theta[i, 0]
        thf[i, 1] = theta[i, 1]
        return True
    return False


@kernel(inline=True)
def _bank_input(b: int, vy: float, vu: float, vz: float, vx: float) -> float:
    """The input of filter bank ``b``: residual output (Y), delayed input (U), instrument input (Z), auxiliary
    output (X)."""
    if b == BY:
        return vy
    if b == BU:
        return vu
    if b == BZ:
        return vz
    return vx


@kernel(inline=True)
def _advance(p00: float, p01: float, p10: float, p11: float, g0: float, g1: float, s0: float, s1: float,
             v: float) -> tuple[float, float]:
    """One ZOH step of a filter state: ``Phi [s0, s1] + Gamma v``."""
    return p00 * s0 + p01 * s1 + g0 * v, p10 * s0 + p11 * s1 + g1 * v


@kernel
def _propagate_mode(i: int, phi: np.ndarray, gam: np.ndarray, xs: np.ndarray, T: np.ndarray,
                    vy: float, vu: float, vz: float, vx: float) -> None:
    """``T[i, b] = Phi_i xs[i, b] + Gamma_i v_b`` for the four banks (t_{k-1} -> t_k). The per-sample loop inlines
    it with scalars (an array argument costs two reference-count updates a call)."""
    for b in range(N_BANKS):
        T[i, b, 0], T[i, b, 1] = _advance(phi[i, 0, 0], phi[i, 0, 1], phi[i, 1, 0], phi[i, 1, 1], gam[i, 0], gam[i, 1],
                                          xs[i, b, 0], xs[i, b, 1], _bank_input(b, vy, vu, vz, vx))


@kernel(inline=True)
def _copy_mode(i: int, theta: np.ndarray, thf: np.ndarray, P: np.ndarray, phi: np.ndarray, gam: np.ndarray,
               theta_to: np.ndarray, thf_to: np.ndarray, P_to: np.ndarray, phi_to: np.ndarray,
               gam_to: np.ndarray) -> None:
    """Mode ``i``'s estimate, filter model, ``P`` and filter discretization into the second set of arrays."""
    for a in range(NT):
        theta_to[i, a] = theta[i, a]
        thf_to[i, a] = thf[i, a]
        for c in range(NT):
            P_to[i, a, c] = P[i, a, c]
    for a in range(2):
        gam_to[i, a] = gam[i, a]
        for c in range(2):
            phi_to[i, a, c] = phi[i, a, c]


def n_kernel_params(kind: int) -> int:
    """Parameters of a mode in the kernel: ``a1, a2, b0``, or a rigid body's ``b0`` and free response ``c0`` (``1/p``)
    or ``c0, c1`` (``1/p^2``); the model's own parameters are the first ``SubmodelStructure.n_theta``."""
    return NT if kind == 0 else 1 + int(kind)


@kernel
def restart_free_response(kind: np.ndarray, theta: np.ndarray, thf: np.ndarray, P: np.ndarray, S: np.ndarray,
                          p0diag: np.ndarray) -> None:
    """The filters start from rest: a rigid body's initial state is unknown again (``c = 0``, ``P(0) = P0_FREE``
    (also its wind-up reference ``p0diag``), no cross or sandwich terms)."""
    for i in range(kind.shape[0]):
        if kind[i] == 0:
            continue
        for a in range(1, NT):
            theta[i, a] = 0.0
            thf[i, a] = 0.0
            for c in range(NT):
                P[i, a, c] = 0.0
                P[i, c, a] = 0.0
                S[i, a, c] = 0.0
                S[i, c, a] = 0.0
        for a in range(1, 1 + kind[i]):
            p0diag[i, a] = P0_FREE
            P[i, a, a] = P0_FREE


@kernel
def free_response_step(i: int, lam: float, e: float, theta: np.ndarray, P: np.ndarray) -> None:
    """RLS of the rigid body's free response alone on the output error ``e = y - sum_i x_i`` (regressor ``[1, 0]``),
    for a sample without an IV update; ``1/p``: ``c1`` and its P stay 0."""
    p00 = P[i, 1, 1]
    p01 = P[i, 1, 2]
    den = lam + p00
    if not (math.isfinite(e) and math.isfinite(den) and den > 0.0):
        return
    g0 = p00 / den
    g1 = p01 / den
    theta[i, 1] += g0 * e
    theta[i, 2] += g1 * e
    p11 = P[i, 2, 2]
    P[i, 1, 1] = (p00 - g0 * p00) / lam
    P[i, 1, 2] = (p01 - g0 * p01) / lam
    P[i, 2, 1] = P[i, 1, 2]
    P[i, 2, 2] = (p11 - g1 * p01) / lam


@kernel
def fold_free_response(i: int, h: float, theta: np.ndarray, thf: np.ndarray, xs: np.ndarray, P: np.ndarray,
                       S: np.ndarray) -> None:
    """End of a sample: the estimated free response ``c0 + c1 t`` joins the rigid body's input filter state as
    ``[c0/b0, c1/b0]`` (``c = 0`` after; kept when ``b0`` is 0 or not finite), and ``P, S`` move to the next sample's
    coordinates (``c0 <- c0 + h c1``: ``P <- F P F^T``, ``S <- F^-T S F^-1``)."""
    b0 = thf[i, 0]
    if b0 != 0.0 and math.isfinite(b0) and math.isfinite(theta[i, 1]) and math.isfinite(theta[i, 2]):
        xs[i, BU, 0] += theta[i, 1] / b0
        xs[i, BU, 1] += theta[i, 2] / b0
        theta[i, 1] = 0.0
        theta[i, 2] = 0.0
        thf[i, 1] = 0.0
        thf[i, 2] = 0.0
    for c in range(NT):
        P[i, 1, c] += h * P[i, 2, c]
        S[i, 2, c] -= h * S[i, 1, c]
    for a in range(NT):
        P[i, a, 1] += h * P[i, a, 2]
        S[i, a, 2] -= h * S[i, a, 1]


@kernel
def run_block(  # noqa: C901 - one compiled per-sample loop (test/test_code_shape.py)
              r: np.ndarray, u: np.ndarray, y: np.ndarray, valid: np.ndarray, allow_update: bool,
              kind: np.ndarray, lam: np.ndarray, muf: np.ndarray, cnum: np.ndarray, cden: np.ndarray,
              cfg_i: np.ndarray, cfg_f: np.ndarray, p0diag: np.ndarray,
              theta: np.ndarray, thf: np.ndarray, P: np.ndarray, S: np.ndarray, xs: np.ndarray, vin: np.ndarray,
              phi: np.ndarray,
              gam: np.ndarray, ubuf: np.ndarray, zbuf: np.ndarray, ce: np.ndarray, cz: np.ndarray,
              ist: np.ndarray, fst: np.ndarray, proj: np.ndarray, rej: np.ndarray, rejr: np.ndarray,
              trace: np.ndarray) -> None:
    """Process a block of samples in place: [RA-SRIVC] Algorithm 2 lines 2-16 for each sample.

    ``allow_update=False`` only filters (priming, Algorithm 2 step 1). ``trace`` (n, K, 3) receives
    theta after every sample when it has n rows (pass a (0, K, 3) array to skip).
    """
    n = r.shape[0]
    K = cfg_i[C_K]
    d = cfg_i[C_DELAY]
    sweeps = cfg_i[C_SWEEPS]
    refine = cfg_i[C_REFINE]
    projection = cfg_i[C_PROJ] != 0
    subsample = cfg_i[C_SUBSAMPLE]
    closed = cfg_i[C_CLOSED] != 0
    hold_len = cfg_i[C_HOLDLEN]
    h = cfg_f[C_H]
    lam_sig = cfg_f[C_LAMSIG]
    max_step = cfg_f[C_MAXSTEP]
    p_cap = cfg_f[C_PCAP]
    nb = cnum.shape[0]
    na = cden.shape[0]
    nbuf = d + 1
    do_trace = trace.shape[0] == n

    # workspace
    T = np.empty((K, N_BANKS, 2))
    # the latest iterate of every mode. One iterate per mode and sample (M_l = 1, M_s = 0, the default) starts from
    # theta_bar(t_{k-1}), P_bar(t_{k-1}) and only the later modes read it: it is written in place (no copies)
    in_place = sweeps * (refine + 1) == 1
    if in_place:
        phi_it = phi
        gam_it = gam
        th_it = theta
        tf_it = thf
        P_it = P
    else:
        phi_it = np.empty((K, 2, 2))
        gam_it = np.empty((K, 2))
        th_it = np.empty((K, NT))
        tf_it = np.empty((K, NT))
        P_it = np.empty((K, NT, NT))
    xu = np.empty(K)
    xh = np.empty(K)
    ytil = np.empty(K)
    ph = np.zeros(NT)
    phh = np.zeros(NT)
    Pph = np.zeros(NT)
    phP = np.zeros(NT)
    gain = np.zeros(NT)
    thn = np.zeros(NT)
    zoh_ok = np.empty(K, dtype=np.bool_)
    Pn = np.zeros((NT, NT))
    zl = np.zeros((K, NT))             # instrument of each mode's accepted iterate (IV sandwich accumulator S)
    lz = np.ones(K)                    # its forgetting factor (1 when capped); 0 = no accepted iterate
    ib0 = np.empty(K, dtype=np.int64)
    ntk = np.empty(K, dtype=np.int64)
    for i in range(K):
        if kind[i] == 0:
            ib0[i] = 2
            ntk[i] = 3
        else:
            ib0[i] = 0
            ntk[i] = 1 + kind[i]   # b0 and the free response c0 (, c1)

    for k in range(n):
        rk = r[k]
        uk = u[k]
        yk = y[k]
        u_ok = math.isfinite(uk)
        r_ok = math.isfinite(rk) or not closed
        ok = valid[k] != 0 and u_ok and r_ok and math.isfinite(yk)
        # an invalid sample gives no update; only the non-finite signals are held (a known input keeps driving
        # the filters, so a skipped output costs no filter transient)
        if not r_ok:
            rk = fst[F_RLAST]
        if not u_ok:
            uk = fst[F_ULAST]
        pos = ist[I_POS]
        ud_prev = ubuf[pos]
        zd_prev = zbuf[pos] if closed else ud_prev
        zb = BZ if closed else BU

        # propagate every bank t_{k-1} -> t_k with theta_bar(t_{k-1}) (cached Phi, Gamma)
        finite = True
        for i in range(K):
            zoh_ok[i] = True
            mode_finite = True
            for b in range(N_BANKS):   # _propagate_mode with scalars (no reference counting in this loop)
                t0, t1 = _advance(phi[i, 0, 0], phi[i, 0, 1], phi[i, 1, 0], phi[i, 1, 1], gam[i, 0], gam[i, 1],
                                  xs[i, b, 0], xs[i, b, 1], _bank_input(b, vin[i, 0], ud_prev, zd_prev, vin[i, 1]))
                T[i, b, 0] = t0
                T[i, b, 1] = t1
                if not (math.isfinite(t0) and math.isfinite(t1)):
                    mode_finite = False
            if not mode_finite and not _finite_zoh(phi[i], gam[i]):
                # the cached Phi, Gamma are the cause (the kernel only caches finite ones: a restored snapshot)
                zoh_ok[i] = _ensure_finite_zoh(i, kind, theta, thf, h, phi, gam)
                if zoh_ok[i]:
                    _propagate_mode(i, phi, gam, xs, T, vin[i, 0], ud_prev, zd_prev, vin[i, 1])
                    mode_finite = True
                    for b in range(N_BANKS):
                        if not (math.isfinite(T[i, b, 0]) and math.isfinite(T[i, b, 1])):
                            mode_finite = False
                else:
                    # no valid discretization of this mode's filters: held at rest, counted; the others run on
                    T[i, :, :] = 0.0
                    rejr[i, R_DISC] += 1
                    mode_finite = True
            if not mode_finite:
                finite = False
        if not finite:
            # re-prime: filters from rest, no updates for hold_len samples (counted)
            T[:, :, :] = 0.0
            ist[I_HOLD] = max(ist[I_HOLD], hold_len)
            ist[I_REPRIMES] += 1
            restart_free_response(kind, theta, thf, P, S, p0diag)
        yhat = 0.0
        for i in range(K):
            xu[i] = thf[i, ib0[i]] * T[i, BU, 0]
            if kind[i] != 0:
                xu[i] += thf[i, 1]   # the rigid body's free response not yet folded (0 unless b0 = 0)
            xh[i] = thf[i, ib0[i]] * T[i, zb, 0]
            yhat += xh[i]
        ysim = 0.0
        for i in range(K):
            ysim += xu[i]
        if not ok:
            yk = ysim  # no information: residual outputs become the model's own outputs
            ist[I_SKIPPED] += 1
        else:
            e = yk - ysim
            fst[F_SIGACC] = lam_sig * fst[F_SIGACC] + (1.0 - lam_sig) * e * e
            fst[F_SIGW] = lam_sig * fst[F_SIGW] + (1.0 - lam_sig)

        do_update = False
        if ok and allow_update:
            if ist[I_HOLD] > 0:
                ist[I_HOLD] -= 1
                ist[I_HELD] += 1
            else:
                do_update = ist[I_SUBCOUNT] % subsample == 0
                ist[I_SUBCOUNT] += 1

        if do_update:
            for i in range(K):
                lz[i] = 0.0
                if not in_place:   # every iterate restarts from theta_bar(t_{k-1}), P_bar(t_{k-1})
                    _copy_mode(i, theta, thf, P, phi, gam, th_it, tf_it, P_it, phi_it, gam_it)
            for _l in range(sweeps):
                for i in range(K):
                    nt = ntk[i]
                    lam_i = lam[i]
                    mu_f = muf[i]
                    for _s in range(refine + 1):
                        # residual output with the other modes' latest iterates ([RA-SRIVC] eq. 22)
                        yt = yk
                        for j in range(K):
                            if j != i:
                                yt -= tf_it[j, ib0[j]] * T[j, BU, 0]
                                if kind[j] != 0:
                                    yt -= tf_it[j, 1]
                        ytil[i] = yt
                        if not zoh_ok[i]:
                            rej[i] += 1    # no filters for this mode (counted per sample in R_DISC above)
                            continue
                        if kind[i] == 0:
                            a1 = tf_it[i, 0]                          # the filters' A (filter model)
                            a2 = tf_it[i, 1]
                            wy = T[i, BY, 0]
                            dwy = T[i, BY, 1]
                            wx = T[i, BX, 0]
                            dwx = T[i, BX, 1]
                            yf = wy                                   # eq. 26
                            ph[0] = -dwy                              # eq. 27
                            ph[1] = -(yt - wy - a1 * dwy) / a2
                            ph[2] = T[i, BU, 0]
                            phh[0] = -dwx                             # eq. 28 / 33
                            phh[1] = -(xh[i] - wx - a1 * dwx) / a2
                            phh[2] = T[i, zb, 0]
                        else:
                            yf = yt                                   # eqs. 34-35, A_1 = 1
                            ph[0] = T[i, BU, 0]
                            phh[0] = T[i, zb, 0]
                            ph[1] = 1.0                               # free response c0 + c1 t (module docstring)
                            phh[1] = 1.0
                            ph[2] = 0.0
                            phh[2] = 0.0
                        # IV-RLS from theta_bar(t_{k-1}), P_bar(t_{k-1}) (Algorithm 2 lines 7-9). Loops over the
                        # parameters run to the constant NT and stop at nt: the compiler unrolls them (same operations,
                        # same order)
                        capped = False
                        for a in range(NT):
                            if a >= nt:
                                break
                            if P[i, a, a] > p_cap * p0diag[i, a]:
                                capped = True
                        lam_eff = 1.0 if capped else lam_i
                        den = lam_eff
                        eps = yf
                        for a in range(NT):
                            if a >= nt:
                                break
                            acc = 0.0
                            acc2 = 0.0
                            for c in range(NT):
                                if c >= nt:
                                    break
                                acc += P[i, a, c] * phh[c]
                                acc2 += ph[c] * P[i, c, a]
                            Pph[a] = acc
                            phP[a] = acc2
                            den += ph[a] * acc
                            eps -= ph[a] * theta[i, a]
                        den_abs = lam_eff
                        if not den >= lam_eff:   # phi^T P phi^ < 0: terms cancel, compare with their magnitude
                            for a in range(NT):
                                if a >= nt:
                                    break
                                for c in range(NT):
                                    if c >= nt:
                                        break
                                    den_abs += abs(ph[a] * P[i, a, c] * phh[c])
                        if not iv_denominator_ok(den, den_abs, lam_eff):
                            rej[i] += 1
                            rejr[i, R_DEN] += 1
                            continue
                        good = math.isfinite(eps)
                        inv_lam = 1.0 / lam_eff   # one division instead of nt^2 (the divider is the bottleneck)
                        if good:
                            for a in range(NT):
                                if a >= nt:
                                    break
                                gain[a] = Pph[a] / den
                                thn[a] = theta[i, a] + gain[a] * eps
                                if not math.isfinite(thn[a]):
                                    good = False
                                if max_step > 0.0 and (kind[i] == 0 or a == 0) and \
                                        abs(thn[a] - theta[i, a]) > max_step * abs(theta[i, a]):
                                    good = False
                                for c in range(NT):
                                    if c >= nt:
                                        break
                                    Pn[a, c] = (P[i, a, c] - gain[a] * phP[c]) * inv_lam
                                    if not math.isfinite(Pn[a, c]):
                                        good = False
                        if good and kind[i] == 0:
                            if thn[1] == 0.0:
                                good = False
                            elif projection:
                                na1, na2, flag = project_second_order(thn[0], thn[1])
                                if flag:
                                    thn[0] = na1
                                    thn[1] = na2
                                    proj[i] += 1
                        if not good:
                            rej[i] += 1
                            rejr[i, R_STEP] += 1
                            continue
                        # filter model of A_i: a_f = mu_f a_f_bar + (1 - mu_f) a (mu_f = 0: Algorithm 2)
                        fa1 = 0.0
                        fa2 = 0.0
                        if kind[i] == 0:
                            if mu_f == 0.0:
                                fa1 = thn[0]
                                fa2 = thn[1]
                            else:
                                fa1 = mu_f * thf[i, 0] + (1.0 - mu_f) * thn[0]
                                fa2 = mu_f * thf[i, 1] + (1.0 - mu_f) * thn[1]
                            n00, n01, n10, n11, ng0, ng1 = zoh_coefficients(fa1, fa2, h)
                            if not _finite_coefficients(n00, n01, n10, n11, ng0, ng1):
                                rej[i] += 1
                                rejr[i, R_DISC] += 1
                                continue
                        if capped:
                            ist[I_CAPPED] += 1
                        lz[i] = lam_eff
                        for a in range(nt):
                            zl[i, a] = phh[a]
                            th_it[i, a] = thn[a]
                            if kind[i] != 0 or a == 2:
                                tf_it[i, a] = thn[a]
                            for c in range(nt):
                                P_it[i, a, c] = Pn[a, c]
                        # filters of this mode follow the new filter model (re-run from the t_{k-1} states)
                        if kind[i] == 0:
                            tf_it[i, 0] = fa1
                            tf_it[i, 1] = fa2
                            phi_it[i, 0, 0] = n00
                            phi_it[i, 0, 1] = n01
                            phi_it[i, 1, 0] = n10
                            phi_it[i, 1, 1] = n11
                            gam_it[i, 0] = ng0
                            gam_it[i, 1] = ng1
                            for b in range(N_BANKS):   # _propagate_mode with the new filter model (scalars)
                                T[i, b, 0], T[i, b, 1] = _advance(
                                    n00, n01, n10, n11, ng0, ng1, xs[i, b, 0], xs[i, b, 1],
                                    _bank_input(b, vin[i, 0], ud_prev, zd_prev, vin[i, 1]))
                            if not finite:
                                T[i, :, :] = 0.0
            for i in range(K):
                if not in_place:
                    _copy_mode(i, th_it, tf_it, P_it, phi_it, gam_it, theta, thf, P, phi, gam)
                if lz[i] > 0.0:   # S follows P: S = lam^2 S + zeta zeta^T, symmetric (IV sandwich, module docstring)
                    l2 = lz[i] * lz[i]
                    m = NT if ntk[i] > 1 else 1    # the rigid body's b0 alone when it has no free response
                    for a in range(m):
                        for c in range(a, m):
                            s_ac = l2 * S[i, a, c] + zl[i, a] * zl[i, c]
                            S[i, a, c] = s_ac
                            S[i, c, a] = s_ac
            ist[I_UPDATES] += 1
        else:
            for i in range(K):
                ytil[i] = yk - (ysim - xu[i])

        # the t_k states replace the t_{k-1} states only now (docs/DESIGN.md, "Conventions")
        for i in range(K):
            for b in range(N_BANKS):
                xs[i, b, 0] = T[i, b, 0]
                xs[i, b, 1] = T[i, b, 1]
            vin[i, 0] = ytil[i]
            vin[i, 1] = xh[i]
            if kind[i] != 0:   # the rigid body's input filter follows the plant's state (module docstring)
                if ok and not do_update:
                    free_response_step(i, lam[i], yk - ysim, theta, P)
                fold_free_response(i, h, theta, thf, xs, P, S)

        # closed-loop instrument input z_k = C_d(q) (r_k - y^_k), [RA-SRIVC] eq. 33 (erratum 3 in docs/DESIGN.md)
        if closed:
            ek = rk - yhat
            zk = cnum[0] * ek
            for j in range(1, nb):
                zk += cnum[j] * ce[j - 1]
            for j in range(1, na):
                zk -= cden[j] * cz[j - 1]
            if not math.isfinite(zk):
                zk = 0.0
                ist[I_NONFINITE_Z] += 1
            for j in range(ce.shape[0] - 1, 0, -1):
                ce[j] = ce[j - 1]
            ce[0] = ek
            for j in range(cz.shape[0] - 1, 0, -1):
                cz[j] = cz[j - 1]
            cz[0] = zk
            zbuf[pos] = zk
        ubuf[pos] = uk
        ist[I_POS] = pos + 1 if pos + 1 < nbuf else 0
        fst[F_RLAST] = rk
        fst[F_ULAST] = uk
        fst[F_YHAT] = yhat
        ist[I_SAMPLES] += 1
        if do_trace:
            for i in range(K):
                for a in range(NT):
                    trace[k, i, a] = theta[i, a]
