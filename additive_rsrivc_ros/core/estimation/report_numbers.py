"""The recursive estimator's per-report numbers: one compiled pass and two batched LAPACK calls, and its closed-loop
state matrix.

Every report publishes, per mode, the modal values and their delta-method stds from the IV sandwich covariance
([RA-SRIVC] §4.2, ``RecursiveAdditiveSRIVC.covariances``), the covariance blocks' problems (a non-finite or indefinite
block reports NaN std, never 0), the loss-of-excitation relative std from ``sigma^2 P_bar`` and the IV condition
numbers. Done per mode with numpy, these are some forty small-array calls per report (0.3 ms for K = 2, a tenth of a
60 s diagnosis); here the arithmetic is one compiled call (the modal arithmetic :func:`.model.second_order_modal`
inlined, :func:`.model.modal_std`), and the eigenvalues (:func:`block_problems`, the rule of
:func:`.recursive.covariance_problem`) and singular values (the condition numbers) of the at most 3 x 3 blocks come
from numpy's LAPACK, one call per block size for all modes.
"""

from __future__ import annotations

import math

import numpy as np

from ..model import second_order_modal, second_order_modal_derivatives
from .compiled import kernel
from .kernel import discretize_mode

#: ``problem`` codes of :func:`report_numbers`, and their names (as :func:`.recursive.covariance_problem` gives)
PROBLEM_NAMES = ("", "non-finite", "indefinite")
# the modal arithmetic's one home (core/model.py), inlined into the kernels
_second_order_modal = kernel(inline=True)(second_order_modal)
_second_order_modal_derivatives = kernel(inline=True)(second_order_modal_derivatives)


def block_problems(blocks: np.ndarray, rel_tol: float) -> np.ndarray:
    """Per square block of ``blocks`` (m, n, n): 0, 1 (non-finite) or 2 (indefinite: the smallest eigenvalue of the
    symmetrized block below ``-rel_tol`` times the largest magnitude, :func:`.recursive.covariance_problem`)."""
    out = np.zeros(blocks.shape[0], dtype=np.int64)
    finite = np.isfinite(blocks).all(axis=(1, 2))
    out[~finite] = 1
    if finite.any() and blocks.shape[1]:
        b = blocks[finite]
        e = np.linalg.eigvalsh(0.5 * (b + b.transpose(0, 2, 1)))        # ascending
        scale = np.maximum(np.maximum(np.abs(e[:, 0]), np.abs(e[:, -1])), 1e-300)
        out[np.flatnonzero(finite)[e[:, 0] < -rel_tol * scale]] = 2
    return out


def condition_numbers(theta: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Condition numbers of the equilibrated IV matrices ``D R D`` (``D = |theta|``, ``R^-1 = P``) of modes with
    ``theta`` (m, n) and ``p`` (m, n, n): NaN when not finite, infinite when singular (0/0 as well, as
    ``np.linalg.cond`` says)."""
    d = 1.0 / np.maximum(np.abs(theta), 1e-300)
    with np.errstate(all="ignore"):
        m = d[:, :, None] * p * d[:, None, :]
    out = np.full(theta.shape[0], np.nan)
    finite = np.isfinite(m).all(axis=(1, 2))
    if finite.any():
        sv = np.linalg.svd(m[finite], compute_uv=False)
        with np.errstate(all="ignore"):
            c = sv[:, 0] / sv[:, -1]
        out[finite] = np.where(np.isnan(c), np.inf, c)
    return out


@kernel
def _modal_values(kind: int, th: np.ndarray, out: np.ndarray) -> None:
    """``[f_hz, zeta, gain]`` (:func:`.model.modal_from_theta`); a rigid body's are ``[0, 0, b0]``."""
    if kind != 0:
        out[0], out[1], out[2] = 0.0, 0.0, th[0]
    elif th[1] > 0.0:
        f_hz, zeta = _second_order_modal(th[0], th[1])
        out[0], out[1], out[2] = f_hz, zeta, th[2]
    else:
        out[0], out[1], out[2] = math.nan, math.nan, th[2]


@kernel
def _modal_stds(kind: int, th: np.ndarray, c: np.ndarray, out: np.ndarray) -> None:
    """Delta-method stds ``sqrt(diag(J C J^T))`` (:func:`.model.modal_std`, [RA-SRIVC] §4.2); negative variance: NaN."""
    if kind != 0:
        var_f, var_z, var_g = 0.0, 0.0, c[0, 0]
    elif th[1] > 0.0:
        jf, jz1, jz2 = _second_order_modal_derivatives(th[0], th[1])   # df/da2, dzeta/da1, dzeta/da2
        var_f = jf * c[1, 1] * jf
        var_z = jz1 * (c[0, 0] * jz1 + c[0, 1] * jz2) + jz2 * (c[1, 0] * jz1 + c[1, 1] * jz2)
        var_g = c[2, 2]
    else:
        var_f, var_z, var_g = math.nan, math.nan, c[2, 2]
    out[0] = math.sqrt(var_f) if var_f >= 0.0 else math.nan
    out[1] = math.sqrt(var_z) if var_z >= 0.0 else math.nan
    out[2] = math.sqrt(var_g) if var_g >= 0.0 else math.nan


@kernel(inline=True)
def _product(x: np.ndarray, y: np.ndarray, rows: int, inner: int, cols: int, y_transposed: bool,
             out: np.ndarray) -> None:
    """``out = x y`` (or ``x y^T``) on the leading ``rows x inner`` and ``inner x cols`` blocks."""
    for a in range(rows):
        for b in range(cols):
            acc = 0.0
            for j in range(inner):
                acc += x[a, j] * (y[b, j] if y_transposed else y[j, b])
            out[a, b] = acc


@kernel
def _sandwich(p: np.ndarray, s: np.ndarray, nk: int, nt: int, scale: float, out: np.ndarray) -> None:
    """``out = scale (c + c^T)`` with ``c = (P S P^T)[:nt, :nt]`` (``scale = sigma^2 / 2``)."""
    ps = np.zeros((3, 3))
    _product(p, s, nt, nk, nk, False, ps)
    c = np.zeros((3, 3))
    _product(ps, p, nt, nk, nt, True, c)
    for a in range(nt):
        for b in range(nt):
            out[a, b] = scale * (c[a, b] + c[b, a])


@kernel
def _relative_std(kind: int, values: np.ndarray, stds: np.ndarray) -> float:
    """The larger relative std of frequency (second-order modes) and gain; NaN when neither is known."""
    best = math.nan
    for q in (0, 2):
        if q == 0 and kind != 0:
            rel = 0.0
        elif values[q] != 0.0:
            rel = abs(stds[q] / values[q])
        elif stds[q] != 0.0:
            rel = math.inf if not math.isnan(stds[q]) else math.nan
        else:
            rel = math.nan                         # 0 / 0
        if not math.isnan(rel) and (math.isnan(best) or rel > best):
            best = rel
    return best


@kernel
def _report_kernel(kind: np.ndarray, theta: np.ndarray, P: np.ndarray, S: np.ndarray, sig2: float, cov: np.ndarray,
                   info: np.ndarray, modal: np.ndarray, info_rel: np.ndarray) -> None:
    """The compiled part of :func:`report_numbers`: ``cov``, ``info``, ``modal`` (values and stds) and ``info_rel``
    of every mode, whatever the blocks' problems."""
    scale = sig2 * 0.5
    stds = np.empty(3)
    for i in range(kind.shape[0]):
        k = kind[i]
        nt = 3 if k == 0 else 1
        nk = 3 if k == 0 else 1 + k
        _sandwich(P[i], S[i], nk, nt, scale, cov[i])
        for a in range(nt):
            for b in range(nt):
                info[i, a, b] = scale * (P[i, a, b] + P[i, b, a])
        _modal_values(k, theta[i], modal[i, :3])
        _modal_stds(k, theta[i], cov[i], modal[i, 3:])
        _modal_stds(k, theta[i], info[i], stds)
        info_rel[i] = _relative_std(k, modal[i, :3], stds)


def report_numbers(kind: np.ndarray, theta: np.ndarray, P: np.ndarray, S: np.ndarray, sig2: float, rel_tol: float,
                   cov: np.ndarray, info: np.ndarray, problem: np.ndarray, info_problem: np.ndarray,
                   modal: np.ndarray, info_rel: np.ndarray, cond: np.ndarray) -> None:
    """Per mode ``i`` (``kind`` 0: second order ``[a1, a2, b0]``; ``l > 0``: rigid body ``b0/p^l``, its free response
    in the kernel slots after ``b0``), into the preallocated outputs:

    - ``cov[i]``: the IV sandwich ``sigma^2 P S P^T`` of the mode's parameters, symmetrized; ``info[i]``:
      ``sigma^2 P`` (symmetrized), both in the leading ``n_theta x n_theta`` block;
    - ``problem[i]``, ``info_problem[i]``: 0, 1 (non-finite) or 2 (indefinite) (:data:`PROBLEM_NAMES`);
    - ``modal[i]``: ``f_hz, zeta, gain`` and, when ``cov[i]`` is usable, their delta-method stds (else NaN);
    - ``info_rel[i]``: the larger relative std of frequency and gain from ``info[i]`` (NaN when unusable);
    - ``cond[i]``: the IV condition number of the mode (NaN when its equilibrated matrix is not finite).
    """
    _report_kernel(kind, theta, P, S, sig2, cov, info, modal, info_rel)
    second = np.asarray(kind) == 0
    for n, sel in ((3, second), (1, ~second)):
        idx = np.flatnonzero(sel)
        if idx.size:
            both = block_problems(np.concatenate((cov[idx, :n, :n], info[idx, :n, :n])), rel_tol)
            problem[idx], info_problem[idx] = both[:idx.size], both[idx.size:]
            cond[idx] = condition_numbers(theta[idx, :n], P[idx, :n, :n])
    modal[problem != 0, 3:] = math.nan
    info_rel[info_problem != 0] = math.nan


@kernel
def closed_loop_state_matrix(kind: np.ndarray, theta: np.ndarray, h: float, delay: int, nump: np.ndarray,
                             denp: np.ndarray, a: np.ndarray) -> None:
    """Fill the zeroed ``a`` (n x n, ``n = nx + delay + nc``) with the state matrix of the noise-free sampled loop
    ``u = C_d(q)(r - y)`` around the frozen ZOH model ([RA-SRIVC] eq. 10; :func:`.recursive.closed_loop_matrix`): per
    mode the kernel's ZOH of ``1/A_i`` (or ``1/p^l``) with output ``b0 w``, then ``delay`` shift states, then ``C_d`` in
    transposed direct form II with ``nump, denp`` (numerator and denominator over ``den[0]``, equal length
    ``nc + 1``)."""
    n = a.shape[0]
    nc = nump.shape[0] - 1
    nx = n - delay - nc
    gam_all = np.zeros(nx)
    c_all = np.zeros(nx)
    phi = np.zeros((2, 2))
    gam = np.zeros(2)
    i = 0
    for m in range(kind.shape[0]):
        k = kind[m]
        if k == 0:
            discretize_mode(0, theta[m, 0], theta[m, 1], h, phi, gam)
            ns, b0 = 2, theta[m, 2]
        else:
            discretize_mode(k, 0.0, 0.0, h, phi, gam)
            ns, b0 = k, theta[m, 0]
        for r in range(ns):
            for col in range(ns):
                a[i + r, i + col] = phi[r, col]
            gam_all[i + r] = gam[r]
        c_all[i] = b0
        i += ns
    dc = nump[0]
    ic = nx + delay                              # controller states s_1..s_nc
    u_row = np.zeros(n)                          # u_k = dc e_k + s_1,k with e_k = -c x_k (r = 0)
    for j in range(nx):
        u_row[j] = -dc * c_all[j]
    if nc:
        u_row[ic] = 1.0
    if delay == 0:
        for r in range(nx):
            for col in range(n):
                a[r, col] += gam_all[r] * u_row[col]
    else:
        for r in range(nx):
            a[r, nx + delay - 1] += gam_all[r]   # the oldest delayed input drives the plant
        for col in range(n):
            a[nx, col] = u_row[col]              # delay line: newest input first
        for k in range(1, delay):
            a[nx + k, nx + k - 1] = 1.0
    for k in range(nc):                          # s_k+ = (n_k - d_k dc) e - d_k s_1 + s_{k+1}
        coef = -(nump[k + 1] - denp[k + 1] * dc)
        for j in range(nx):
            a[ic + k, j] = coef * c_all[j]
        a[ic + k, ic] -= denp[k + 1]
        if k + 1 < nc:
            a[ic + k, ic + k + 1] += 1.0
