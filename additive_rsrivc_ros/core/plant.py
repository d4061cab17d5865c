"""Exact ZOH response of the additive modal plant (ROS-free; numba per-sample loop).

The plant of [RA-SRIVC] eq. 5 / [A-SRIVC] eq. 2 (:mod:`..sim.simulate`), ``u`` held between samples and delayed ``d``
samples. :func:`simulate_kernel` advances it sample by sample with parameters that may change at every sample;
:func:`open_loop_output` is a fixed model's response to a given input (``core.modefind``); :func:`discrete_plant`,
:func:`closed_loop_poles` and :func:`loop_margins` analyse the frozen loop. Each mode's transition is exact:
:func:`.zoh.second_order_zoh`, :func:`.zoh.integrator_chain_zoh`, and a compiled scaling-and-squaring matrix exponential
for ``b0/(p^l A(p))`` with ``l > 0``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from .controller import DiscreteController
from .estimation.compiled import kernel
from .estimation.zoh import integrator_chain_zoh, second_order_zoh
from .model import TWO_PI, SubmodelStructure, parallel_state_space

_KIND_SECOND, _KIND_CHAIN, _KIND_GENERAL = 0, 1, 2


# ----------------------------------------------------------------------------------------------------------------
# Compiled per-sample kernel
# ----------------------------------------------------------------------------------------------------------------
@kernel
def _expm_small(m: np.ndarray) -> np.ndarray:
    """Matrix exponential of a small matrix: scaling and squaring with an 18-term Taylor series (error ~ ulp)."""
    n = m.shape[0]
    norm = 0.0
    for i in range(n):
        row = 0.0
        for j in range(n):
            row += abs(m[i, j])
        norm = max(norm, row)
    s = 0
    if norm > 0.25:                 # s = ceil(log2(norm / 0.25)), exactly: frexp gives x = f 2^e, f in [0.5, 1)
        f, e = math.frexp(norm / 0.25)      # (math.log2 compiles only with numba >= 0.60)
        s = e - 1 if f == 0.5 else e
    a = m / (2.0**s)
    result = np.eye(n)
    term = np.eye(n)
    for k in range(1, 19):
        term = term @ a / k
        result = result + term
    for _ in range(s):
        result = result @ result
    return result


@kernel
def _mode_zoh(kind: int, l: int, a1: float, a2: float, b0: float, h: float, phi: np.ndarray,
              gamma: np.ndarray) -> None:
    """Exact ZOH of one mode in output coordinates ``[x, x', ...]``, input ``u`` (the gain is in ``gamma``)."""
    if kind == 0:
        p2 = np.zeros((2, 2))
        g2 = np.zeros(2)
        second_order_zoh(a1, a2, h, p2, g2)
        phi[:2, :2] = p2
        gamma[0] = g2[0] * b0
        gamma[1] = g2[1] * b0
    elif kind == 1:
        pc = np.zeros((l, l))
        gc = np.zeros(l)
        integrator_chain_zoh(l, h, pc, gc)
        phi[:l, :l] = pc
        for i in range(l):
            gamma[i] = gc[i] * b0
    else:
        ns = l + 2
        aug = np.zeros((ns + 1, ns + 1))
        for i in range(ns - 1):
            aug[i, i + 1] = h
        aug[ns - 1, l] = -h / a2
        aug[ns - 1, l + 1] = -h * a1 / a2
        aug[ns - 1, ns] = h * b0 / a2
        e = _expm_small(aug)
        phi[:ns, :ns] = e[:ns, :ns]
        for i in range(ns):
            gamma[i] = e[i, ns]


@kernel
def simulate_kernel(theta: np.ndarray, kinds: np.ndarray, ls: np.ndarray, h: float, closed: bool,
                     r: np.ndarray, u_ext: np.ndarray, v: np.ndarray, delay: int, num: np.ndarray,
                     den: np.ndarray, add: np.ndarray, stuck: np.ndarray, stuck_val: np.ndarray,
                     hold: np.ndarray, nanmask: np.ndarray, u: np.ndarray, y: np.ndarray, x: np.ndarray,
                     e: np.ndarray) -> None:
    """Per-sample loop ([RA-SRIVC] eq. 10 closed loop): output at t_k, control u(t_k), then advance with u(t_{k-d})."""
    n, kmodes = theta.shape[0], theta.shape[1]
    ns_max = 5
    z = np.zeros((kmodes, ns_max))
    phi = np.zeros((kmodes, ns_max, ns_max))
    gam = np.zeros((kmodes, ns_max))
    last = np.full((kmodes, 3), np.nan)
    nst = np.zeros(kmodes, dtype=np.int64)
    for i in range(kmodes):
        nst[i] = 2 if kinds[i] == 0 else (ls[i] if kinds[i] == 1 else ls[i] + 2)
    zn = np.zeros(ns_max)
    last_meas = 0.0
    last_finite = 0.0
    for k in range(n):
        xk = 0.0
        for i in range(kmodes):
            xk += z[i, 0]
        x[k] = xk
        meas = xk + v[k] + add[k]
        if stuck[k]:
            meas = stuck_val[k]
        if hold[k] and k > 0:
            meas = last_meas
        last_meas = meas
        if nanmask[k]:
            y[k] = np.nan
        else:
            y[k] = meas
            last_finite = meas
        if closed:
            e[k] = r[k] - last_finite
            acc = 0.0
            for j in range(num.size):
                if k - j >= 0:
                    acc += num[j] * e[k - j]
            for j in range(1, den.size):
                if k - j >= 0:
                    acc -= den[j] * u[k - j]
            u[k] = acc
        else:
            u[k] = u_ext[k]
        ud = u[k - delay] if k - delay >= 0 else 0.0
        for i in range(kmodes):
            a1, a2, b0 = theta[k, i, 0], theta[k, i, 1], theta[k, i, 2]
            if a1 != last[i, 0] or a2 != last[i, 1] or b0 != last[i, 2]:
                _mode_zoh(kinds[i], ls[i], a1, a2, b0, h, phi[i], gam[i])
                last[i, 0], last[i, 1], last[i, 2] = a1, a2, b0
            m = nst[i]
            for a in range(m):
                acc = gam[i, a] * ud
                for b in range(m):
                    acc += phi[i, a, b] * z[i, b]
                zn[a] = acc
            for a in range(m):
                z[i, a] = zn[a]


# ----------------------------------------------------------------------------------------------------------------
# Inputs of the kernel
# ----------------------------------------------------------------------------------------------------------------
def check_drive(drive: np.ndarray, n: int | None, rate_hz: float, input_delay: int) -> tuple[np.ndarray, int]:
    """The reference (closed loop) or input (open loop) as a finite 1-D float array of ``n`` samples (default: its
    length), with a valid rate and delay; ValueError otherwise."""
    drive = np.asarray(drive, dtype=float)
    if drive.ndim != 1:
        raise ValueError("r/u must be one-dimensional")
    n = drive.size if n is None else n
    if drive.size != n:
        raise ValueError(f"r/u has {drive.size} samples, expected {n}")
    if not np.all(np.isfinite(drive)):
        raise ValueError("r/u must be finite")
    if not (rate_hz > 0 and math.isfinite(rate_hz)):
        raise ValueError(f"rate_hz must be > 0, got {rate_hz}")
    if input_delay < 0:
        raise ValueError(f"input_delay must be >= 0, got {input_delay}")
    return drive, n


def pack_thetas(thetas: Sequence[np.ndarray], structures: Sequence[SubmodelStructure],
                n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[np.ndarray]]:
    """Kernel arrays ``(theta (N, K, 3), kinds, integrators, per-mode (N, n_theta) thetas)`` from ``thetas[i]``
    of shape ``(N, n_theta_i)`` or ``(n_theta_i,)`` (constant; [RA-SRIVC] eq. 7 order). A mode must be
    ``b0/(p^l A)`` with deg A = 2, or a rigid body (deg A = 0, l >= 1); ValueError otherwise."""
    kmodes = len(structures)
    theta = np.zeros((n, kmodes, 3))
    kinds = np.zeros(kmodes, dtype=np.int64)
    ls = np.zeros(kmodes, dtype=np.int64)
    full_thetas = []
    for i, (th, s) in enumerate(zip(thetas, structures, strict=True)):
        th = np.asarray(th, dtype=float)
        th = np.broadcast_to(th, (n, s.n_theta)) if th.ndim == 1 else th
        if th.shape != (n, s.n_theta):
            raise ValueError(f"mode {i}: theta has shape {th.shape}, expected ({n}, {s.n_theta})")
        if not np.all(np.isfinite(th)):
            raise ValueError(f"mode {i}: theta must be finite")
        if s.m != 0 or s.n not in (0, 2):
            raise ValueError(f"mode {i}: the simulator supports b0/(p^l A) with deg A in (0, 2), got {s}")
        if s.n == 0:
            if s.integrators < 1:
                raise ValueError(f"mode {i}: a rigid-body mode needs integrators >= 1")
            kinds[i], theta[:, i, 2] = _KIND_CHAIN, th[:, 0]
        else:
            if np.any(th[:, 1] <= 0.0):
                raise ValueError(f"mode {i}: a2 must be > 0")
            kinds[i] = _KIND_SECOND if s.integrators == 0 else _KIND_GENERAL
            theta[:, i, :] = th
        if s.integrators > 3:
            raise ValueError(f"mode {i}: at most 3 integrators supported")
        ls[i] = s.integrators
        full_thetas.append(np.array(th))
    return theta, kinds, ls, full_thetas


def open_loop_output(thetas: Sequence[np.ndarray], structures: Sequence[SubmodelStructure], rate_hz: float,
                     u: np.ndarray, input_delay: int = 0) -> np.ndarray:
    """Noise-free output ``x(t_k)`` of the model driven by ``u`` (ZOH, delayed ``input_delay`` samples)."""
    if len(thetas) != len(structures) or len(thetas) == 0:
        raise ValueError("need one theta trajectory per structure and at least one mode")
    drive, n = check_drive(u, None, rate_hz, input_delay)
    theta, kinds, ls, _ = pack_thetas(thetas, structures, n)
    no = np.zeros(n, dtype=np.bool_)
    zero = np.zeros(n)
    u_out, y, x, e = np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n)
    simulate_kernel(theta, kinds, ls, 1.0 / rate_hz, False, drive, drive, zero, input_delay, np.zeros(1),
                    np.ones(1), zero, no, zero, no, no, u_out, y, x, e)
    return y


# ----------------------------------------------------------------------------------------------------------------
# Closed-loop analysis
# ----------------------------------------------------------------------------------------------------------------
def discrete_mode_blocks(thetas: Sequence[np.ndarray], structures: Sequence[SubmodelStructure],
                         rate_hz: float) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per submodel the exact ZOH ``(Phi_i, Gamma_i, c_i)`` of ``B_i/(p^l A_i)`` ([RA-SRIVC] eq. 10, without the delay):
    the blocks of :func:`discrete_plant`."""
    h = 1.0 / rate_hz
    blocks = []
    for th, s in zip(thetas, structures, strict=True):
        th = np.asarray(th, float)
        kind = _KIND_CHAIN if s.n == 0 else (_KIND_SECOND if s.integrators == 0 else _KIND_GENERAL)
        ns = 2 if kind == _KIND_SECOND else (s.integrators if kind == _KIND_CHAIN else s.integrators + 2)
        phi, gam = np.zeros((5, 5)), np.zeros(5)
        a1, a2, b0 = (0.0, 0.0, th[0]) if s.n == 0 else (th[0], th[1], th[2])
        _mode_zoh(kind, s.integrators, a1, a2, b0, h, phi, gam)
        c = np.zeros(ns)
        c[0] = 1.0
        blocks.append((phi[:ns, :ns], gam[:ns], c))
    return blocks


def discrete_plant(thetas: Sequence[np.ndarray], structures: Sequence[SubmodelStructure], rate_hz: float,
                   input_delay: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact ZOH state-space ``(Phi, Gamma, C)`` of the frozen plant ``sum_i B_i/(p^l A_i)`` with the delay
    as extra shift states ([RA-SRIVC] eq. 10): ``x_{k+1} = Phi x_k + Gamma u_k``, ``y_k = C x_k``."""
    phi, gam, c = parallel_state_space(discrete_mode_blocks(thetas, structures, rate_hz))
    nx = phi.shape[0]
    if input_delay:
        d = input_delay
        big = np.zeros((nx + d, nx + d))
        big[:nx, :nx] = phi
        big[:nx, nx + d - 1] = gam  # oldest delayed input drives the plant
        for j in range(d - 1, 0, -1):
            big[nx + j, nx + j - 1] = 1.0
        g = np.zeros(nx + d)
        g[nx] = 1.0
        phi, gam, c = big, g, np.concatenate((c, np.zeros(d)))
    return phi, gam, c


def closed_loop_poles(thetas: Sequence[np.ndarray], structures: Sequence[SubmodelStructure],
                      controller: DiscreteController, rate_hz: float, input_delay: int = 0) -> np.ndarray:
    """Eigenvalues of the sampled loop ``u = C_d (r - y)`` around the frozen ZOH plant ([RA-SRIVC] eq. 10)."""
    from scipy import signal

    phi, gam, c = discrete_plant(thetas, structures, rate_hz, input_delay)
    num, den = controller.num, controller.den
    nc = max(num.size, den.size) - 1
    nump, denp = np.zeros(nc + 1), np.zeros(nc + 1)
    nump[: num.size], denp[: den.size] = num, den
    if nc == 0:
        ac, bc, cc, dc = np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), np.array([[nump[0]]])
    else:
        ac, bc, cc, dc = signal.tf2ss(nump, denp)  # q^-1 polynomials of equal length = z polynomials
    nx = phi.shape[0]
    # u = Cc xc + Dc (r - C x);  x+ = Phi x + Gamma u;  xc+ = Ac xc + Bc (r - C x)
    top = np.hstack((phi - np.outer(gam, c) * dc[0, 0], gam[:, None] @ cc))
    bot = np.hstack((-bc @ c[None, :], ac))
    a = np.vstack((top, bot)) if nc else top
    assert a.shape == (nx + nc, nx + nc)
    return np.linalg.eigvals(a)


def loop_margins(thetas: Sequence[np.ndarray], structures: Sequence[SubmodelStructure],
                 controller: DiscreteController, rate_hz: float, input_delay: int = 0,
                 n_freq: int = 20000) -> dict[str, float]:
    """Modulus margin ``min |1 + C_d G_d|`` and the largest closed-loop pole modulus of the frozen loop."""
    phi, gam, c = discrete_plant(thetas, structures, rate_hz, input_delay)
    f = np.geomspace(1e-3, rate_hz / 2 * 0.999, n_freq)
    zs = np.exp(1j * TWO_PI * f / rate_hz)
    eye = np.eye(phi.shape[0])
    g = np.array([c @ np.linalg.solve(z * eye - phi, gam) for z in zs])
    loop = 1.0 + controller.frequency_response(f, rate_hz) * g
    poles = closed_loop_poles(thetas, structures, controller, rate_hz, input_delay)
    return {"modulus_margin": float(np.min(np.abs(loop))), "max_pole": float(np.max(np.abs(poles)))}
