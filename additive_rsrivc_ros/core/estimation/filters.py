"""ZOH-exact discrete state-variable filters for the offline SRIVC family ([A-SRIVC] eqs. 10, 20, 24, 31-32).

Every continuous-time filter is realized in state space and discretized exactly for a held input (``Phi, Gamma`` from
the matrix exponential, :func:`.zoh.zoh_matrices`; Tustin biased the closed-loop estimates by 1-4 stds). No high-order
polynomial is formed: ``p^j / (p^l A(p))`` is a *scaled* companion realization (``expm`` works on ``||A h|| ~ omega
h``); the instrument filters ``p^j B / (p^l A^2)`` (eqs. 10, 20, 31) are one cascade ``B/(p^l A)`` then ``1/A``, exact
for a held input; the closed loop's total model (eq. 20, ``S_uo = C_d / (1 + C_d G_d)``, erratum 3 in docs/DESIGN.md) is
the parallel sum of the submodels. Long signals run through compiled loops (:mod:`.compiled`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..controller import DiscreteController
from ..model import SubmodelStructure, parallel_state_space, split_theta
from .compiled import kernel
from .zoh import zoh_matrices

# a continuous realization (A, B, C, D)
StateSpace = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]


class ClosedLoopUnstableError(ValueError):
    """The controller does not stabilize the (ZOH-equivalent) model: ``S_uo r`` would diverge."""


@dataclass(frozen=True)
class DiscreteSS:
    """A ZOH-discretized SISO-input state-space filter with several outputs.

    ``x_{k+1} = phi x_k + gamma v_k``, ``Y_k = c x_k + d v_k`` (``c``: (n_out, n), ``d``: (n_out,)).
    """

    phi: np.ndarray
    gamma: np.ndarray
    c: np.ndarray
    d: np.ndarray

    @property
    def n_states(self) -> int:
        return self.phi.shape[0]

    def run(self, v: np.ndarray, rows=None, out: np.ndarray | None = None, sign: float = 1.0) -> np.ndarray:
        """Filter the held input ``v`` from rest; returns (N, n_out) (or only the output ``rows``).

        ``out`` (optional, (N, len(rows)), may be a column slice of a larger array) receives
        ``sign * outputs`` without temporaries (compiled loop).
        """
        v = np.ascontiguousarray(v, dtype=float)
        c, d = (self.c, self.d) if rows is None else (self.c[list(rows)], self.d[list(rows)])
        if out is None:
            out = np.empty((v.size, c.shape[0]))
        if c.shape[0] == 0:
            return out
        run_outputs(self.phi, self.gamma, np.ascontiguousarray(sign * c), np.ascontiguousarray(sign * d), v, out)
        return out


# --------------------------------------------------------------------------------------------------
# compiled loops


@kernel
def _run_outputs_2(phi: np.ndarray, gamma: np.ndarray, c: np.ndarray, d: np.ndarray, v: np.ndarray,
                   out: np.ndarray) -> None:
    """:func:`run_outputs` for two states (every resonant mode's filter) with the state in registers."""
    p00, p01, p10, p11 = phi[0, 0], phi[0, 1], phi[1, 0], phi[1, 1]
    g0, g1 = gamma[0], gamma[1]
    x0 = 0.0
    x1 = 0.0
    for k in range(v.shape[0]):
        vk = v[k]
        for j in range(c.shape[0]):
            out[k, j] = d[j] * vk + c[j, 0] * x0 + c[j, 1] * x1
        x0, x1 = p00 * x0 + p01 * x1 + g0 * vk, p10 * x0 + p11 * x1 + g1 * vk


@kernel
def _run_outputs_4(phi: np.ndarray, gamma: np.ndarray, c: np.ndarray, d: np.ndarray, v: np.ndarray,
                   out: np.ndarray) -> None:
    """:func:`run_outputs` for four states (one mode's instrument cascade ``B/A`` then ``1/A``) in registers."""
    p00, p01, p02, p03 = phi[0, 0], phi[0, 1], phi[0, 2], phi[0, 3]
    p10, p11, p12, p13 = phi[1, 0], phi[1, 1], phi[1, 2], phi[1, 3]
    p20, p21, p22, p23 = phi[2, 0], phi[2, 1], phi[2, 2], phi[2, 3]
    p30, p31, p32, p33 = phi[3, 0], phi[3, 1], phi[3, 2], phi[3, 3]
    g0, g1, g2, g3 = gamma[0], gamma[1], gamma[2], gamma[3]
    x0 = 0.0
    x1 = 0.0
    x2 = 0.0
    x3 = 0.0
    for k in range(v.shape[0]):
        vk = v[k]
        for j in range(c.shape[0]):
            out[k, j] = d[j] * vk + c[j, 0] * x0 + c[j, 1] * x1 + c[j, 2] * x2 + c[j, 3] * x3
        x0, x1, x2, x3 = (p00 * x0 + p01 * x1 + p02 * x2 + p03 * x3 + g0 * vk,
                          p10 * x0 + p11 * x1 + p12 * x2 + p13 * x3 + g1 * vk,
                          p20 * x0 + p21 * x1 + p22 * x2 + p23 * x3 + g2 * vk,
                          p30 * x0 + p31 * x1 + p32 * x2 + p33 * x3 + g3 * vk)


@kernel
def run_outputs(phi: np.ndarray, gamma: np.ndarray, c: np.ndarray, d: np.ndarray, v: np.ndarray,
                out: np.ndarray) -> None:
    """``out[k] = c x_k + d v_k`` with ``x_{k+1} = phi x_k + gamma v_k``, ``x_0 = 0`` (one pass, no temporaries)."""
    n = phi.shape[0]
    if n == 2:
        _run_outputs_2(phi, gamma, c, d, v, out)
        return
    if n == 4:
        _run_outputs_4(phi, gamma, c, d, v, out)
        return
    n_out = c.shape[0]
    x = np.zeros(n)
    xn = np.zeros(n)
    for k in range(v.shape[0]):
        vk = v[k]
        for j in range(n_out):
            acc = d[j] * vk
            for i in range(n):
                acc += c[j, i] * x[i]
            out[k, j] = acc
        for i in range(n):  # x_{k+1} = phi x_k + gamma v_k into the other buffer, then swap (no copy back:
            acc = gamma[i] * vk  # a copy through memory puts a store-to-load round trip on the critical path)
            for j in range(n):
                acc += phi[i, j] * x[j]
            xn[i] = acc
        x, xn = xn, x


@kernel
def _closed_loop_loop(phi, gamma, cp, dp, delay, cnum, cden, r):  # pragma: no cover - compiled
    """Noise-free closed loop ``u = C_d (r - G_d q^-d u)`` (DF-II transposed controller, [A-SRIVC] eq. 6)."""
    n = phi.shape[0]
    nsamp = r.shape[0]
    nc = cnum.shape[0] - 1
    u_out = np.empty(nsamp)
    y_out = np.empty(nsamp)
    x = np.zeros(n)
    xn = np.zeros(n)
    w = np.zeros(nc + 1)
    buf = np.zeros(delay + 1)  # circular buffer of past inputs
    pos = 0                    # its slot of u_{k-d} (a running index: no integer division per sample)
    c0 = cnum[0]
    for k in range(nsamp):
        yx = 0.0
        for i in range(n):
            yx += cp[i] * x[i]
        if delay == 0:
            # algebraic loop only through a biproper model: u = (c0 (r - C x) + w1) / (1 + c0 D)
            u = (c0 * (r[k] - yx) + w[0]) / (1.0 + c0 * dp)
            ud = u
        else:
            ud = buf[pos]
            u = c0 * (r[k] - yx - dp * ud) + w[0]
        y = yx + dp * ud
        e = r[k] - y
        for i in range(nc):
            w[i] = cnum[i + 1] * e - cden[i + 1] * u + w[i + 1]
        if delay > 0:
            buf[pos] = u
            pos += 1
            if pos == delay:
                pos = 0
        for i in range(n):  # x_{k+1} = phi x_k + gamma v_k into the other buffer, then swap (no copy back:
            acc = gamma[i] * ud  # a copy through memory puts a store-to-load round trip on the critical path)
            for j in range(n):
                acc += phi[i, j] * x[j]
            xn[i] = acc
        x, xn = xn, x
        u_out[k] = u
        y_out[k] = y
    return u_out, y_out


# --------------------------------------------------------------------------------------------------
# continuous-time realizations


def _scale(den: np.ndarray) -> float:
    """Time scale ``s = |d_top|^(-1/order)`` that equilibrates a companion realization."""
    order = den.size - 1
    s = abs(den[-1]) ** (-1.0 / order)
    return s if np.isfinite(s) and s > 0 else 1.0


def svf_continuous(a: np.ndarray, integrators: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Scaled companion realization of ``p^j / (p^l A(p))``, j = 0..n+l ([RA-SRIVC] eqs. 26-28, [A-SRIVC] eq. 24).

    ``a`` ascending, ``a[0] = 1``. Returns continuous ``(A, B, C, D)`` with ``C``: (n+l+1, n+l); only the
    last output (``p^(n+l)/(p^l A)``) has a direct term.
    """
    a = np.asarray(a, dtype=float)
    den = np.concatenate((np.zeros(integrators), a))
    order = den.size - 1
    if order == 0:
        return np.zeros((0, 0)), np.zeros(0), np.zeros((1, 0)), np.array([1.0 / den[0]])
    top = den[-1]
    if top == 0.0 or not np.isfinite(top):
        raise ValueError(f"leading coefficient of A(p) must be finite and non-zero, got {top}")
    s = _scale(den)
    sp = s ** np.arange(order)
    A = np.zeros((order, order))
    A[np.arange(order - 1), np.arange(1, order)] = s
    A[-1, :] = -den[:-1] * sp / (top * s ** (order - 1))
    B = np.zeros(order)
    B[-1] = 1.0 / (top * s ** (order - 1))
    C = np.zeros((order + 1, order))
    C[np.arange(order), np.arange(order)] = sp
    C[order, :] = -den[:-1] * sp / top
    D = np.zeros(order + 1)
    D[order] = 1.0 / top
    return A, B, C, D


def submodel_continuous(theta: np.ndarray, st: SubmodelStructure) -> StateSpace:
    """Realization ``(A, B, C, D)`` of ``B(p) / (p^l A(p))`` (one output), [A-SRIVC] eq. 2 / Remark 6."""
    a, b = split_theta(theta, st)
    A, Bv, C, D = svf_continuous(a, st.integrators)
    bb = np.zeros(st.n + st.integrators + 1)
    bb[: b.size] = b
    return A, Bv, bb @ C, np.array([bb @ D])


def instrument_continuous(theta: np.ndarray, st: SubmodelStructure) -> StateSpace:
    """Cascade ``B/(p^l A)`` then ``1/A``: outputs ``p^j B / (p^l A^2)``, j = 0..n ([A-SRIVC] eqs. 10, 20, 31)."""
    a, b = split_theta(theta, st)
    return instrument_continuous_poly(a, b, st.integrators)


def instrument_continuous_poly(a: np.ndarray, b: np.ndarray, integrators: int = 0) -> StateSpace:
    """:func:`instrument_continuous` for any denominator ``A`` (ascending; anti-monic or monic, [UNS-SRIVC] §6)."""
    a = np.asarray(a, dtype=float)
    A1, B1, C1, D1 = svf_continuous(a, integrators)
    bb = np.zeros(a.size + integrators)
    bb[: len(b)] = b
    C1, D1 = bb @ C1, np.array([bb @ D1])
    A2, B2, C2, D2 = svf_continuous(a, 0)
    n1, n2 = A1.shape[0], A2.shape[0]
    A = np.zeros((n1 + n2, n1 + n2))
    A[:n1, :n1] = A1
    A[n1:, :n1] = np.outer(B2, C1)
    A[n1:, n1:] = A2
    B = np.concatenate((B1, B2 * D1[0]))
    C = np.hstack((np.outer(D2, C1), C2))
    D = D2 * D1[0]
    return A, B, C, D


def discretize(A: np.ndarray, B: np.ndarray, C: np.ndarray, D: np.ndarray, h: float) -> DiscreteSS:
    """Exact ZOH of a continuous realization (augmented-matrix exponential, :func:`core.zoh.zoh_matrices`)."""
    n = A.shape[0]
    if n == 0:
        d = np.atleast_1d(np.asarray(D, float))
        return DiscreteSS(np.zeros((0, 0)), np.zeros(0), np.zeros((d.size, 0)), d)
    phi, gam = zoh_matrices(A, B, h)
    out = DiscreteSS(np.ascontiguousarray(phi), np.ascontiguousarray(gam[:, 0]),
                     np.atleast_2d(np.asarray(C, float)), np.atleast_1d(np.asarray(D, float)))
    if not (np.all(np.isfinite(out.phi)) and np.all(np.isfinite(out.gamma))):
        raise ValueError("ZOH discretization produced non-finite values (model coefficients out of range)")
    return out


# --------------------------------------------------------------------------------------------------
# the filter bank used by the estimators


def delay_signal(v: np.ndarray, delay: int) -> np.ndarray:
    """``v(t_k - d h)`` with zeros before the first sample (known input delay, in samples)."""
    v = np.asarray(v, dtype=float)
    if delay <= 0:
        return v
    out = np.zeros_like(v)
    out[delay:] = v[:-delay]
    return out


def svf(a: np.ndarray, v: np.ndarray, h: float, integrators: int = 0) -> np.ndarray:
    """ZOH-exact ``p^j / (p^l A(p)) v``, j = 0..n+l, as columns of an (N, n+l+1) array ([A-SRIVC] eq. 24/32)."""
    return discretize(*svf_continuous(a, integrators), h).run(v)


def submodel_output(theta: np.ndarray, st: SubmodelStructure, v: np.ndarray, h: float) -> np.ndarray:
    """Simulated submodel output ``B/(p^l A) v`` (ZOH-exact) from rest, [A-SRIVC] eq. 23."""
    return discretize(*submodel_continuous(theta, st), h).run(v)[:, 0]


def instrument_filter(theta: np.ndarray, st: SubmodelStructure, v: np.ndarray, h: float) -> np.ndarray:
    """ZOH-exact ``p^j B / (p^l A^2) v``, j = 0..n, one cascade filter of the held ``v`` ([A-SRIVC] eqs. 10, 20, 31)."""
    return discretize(*instrument_continuous(theta, st), h).run(v)


def total_model_discrete(thetas: list[np.ndarray], structures: list[SubmodelStructure], h: float) -> DiscreteSS:
    """ZOH equivalent of the additive model ``sum_i B_i/(p^l_i A_i)`` as a block-diagonal state space."""
    blocks = [discretize(*submodel_continuous(th, st), h) for th, st in zip(thetas, structures, strict=True)]
    phi, gam, c = parallel_state_space([(b.phi, b.gamma, b.c[0]) for b in blocks])
    return DiscreteSS(phi, gam, c[None, :], np.array([sum((float(b.d[0]) for b in blocks), 0.0)]))


DENSE_MAX_DIM = 400
"""States up to which :func:`closed_loop_matrix` is dense and its eigenvalues are all computed."""


def closed_loop_matrix(plant: DiscreteSS, controller: DiscreteController, delay: int = 0):
    """Autonomous matrix of the noise-free loop ``u = C_d (r - q^-d G_d u)`` (state: plant, delay, controller).

    Dense up to :data:`DENSE_MAX_DIM` states, else a scipy sparse matrix (a long delay line is a shift; scipy is
    imported only then: it costs 0.2 s at the start of every tool and the node); its spectral radius decides
    stability.
    """
    n = plant.n_states
    cnum, cden = _controller_arrays(controller)
    nc = cnum.size - 1
    cp, dp = plant.c[0], float(plant.d[0])
    c0 = cnum[0]
    dim = n + delay + nc
    # u_k = L xi_k (r = 0); xi = [x, delta_1..delta_d (delta_j = u_{k-j}), w_1..w_nc]
    L = np.zeros(dim)
    if delay == 0:
        den = 1.0 + c0 * dp
        if den == 0.0:
            raise ClosedLoopUnstableError("the closed loop is ill-posed (1 + C_d(inf) G_d(inf) = 0)")
        L[:n] = -c0 * cp / den
        if nc:
            L[n + delay] = 1.0 / den
    else:
        L[:n] = -c0 * cp
        L[n + delay - 1] = -c0 * dp
        if nc:
            L[n + delay] = 1.0
    Y = np.zeros(dim)  # y_k = Y xi_k
    Y[:n] = cp
    if delay == 0:
        Y += dp * L
    else:
        Y[n + delay - 1] += dp
    rows, cols, vals = [], [], []

    def add(i: int, vec: np.ndarray) -> None:
        nz = np.flatnonzero(vec)
        rows.extend([i] * nz.size)
        cols.extend(nz.tolist())
        vals.extend(vec[nz].tolist())

    ud = L if delay == 0 else np.eye(1, dim, n + delay - 1)[0]
    for i in range(n):
        vec = np.zeros(dim)
        vec[:n] = plant.phi[i]
        vec += plant.gamma[i] * ud
        add(i, vec)
    if delay > 0:
        add(n, L)
        for j in range(1, delay):
            rows.append(n + j)
            cols.append(n + j - 1)
            vals.append(1.0)
    for i in range(nc):
        vec = -cnum[i + 1] * Y - cden[i + 1] * L
        if i + 1 < nc:
            vec = vec.copy()
            vec[n + delay + i + 1] += 1.0
        add(n + delay + i, vec)
    if dim <= DENSE_MAX_DIM:
        mat = np.zeros((dim, dim))
        mat[rows, cols] = vals           # one entry per (row, column): every row is built once
        return mat
    import scipy.sparse

    return scipy.sparse.csr_matrix((vals, (rows, cols)), shape=(dim, dim))


def spectral_radius(mat) -> float:
    """Largest eigenvalue modulus of a :func:`closed_loop_matrix` (dense: all eigenvalues; sparse: ARPACK, and dense
    again if ARPACK does not converge: a long delay line puts many eigenvalues on one circle, where Arnoldi can
    stall)."""
    dim = mat.shape[0]
    if dim == 0:
        return 0.0
    if isinstance(mat, np.ndarray):
        return float(np.max(np.abs(np.linalg.eigvals(mat))))
    import scipy.sparse.linalg

    try:
        val = scipy.sparse.linalg.eigs(mat.tocsc(), k=1, which="LM", return_eigenvectors=False, maxiter=20 * dim,
                                       v0=np.ones(dim))    # fixed start vector: the same answer every run
        return float(np.abs(val[0]))
    except scipy.sparse.linalg.ArpackNoConvergence:
        return float(np.max(np.abs(np.linalg.eigvals(mat.toarray()))))


def _controller_arrays(controller: DiscreteController) -> tuple[np.ndarray, np.ndarray]:
    num, den = controller.num, controller.den
    size = max(num.size, den.size)
    cnum = np.zeros(size)
    cden = np.zeros(size)
    cnum[: num.size] = num
    cden[: den.size] = den
    return cnum, cden


def closed_loop_radius(thetas: list[np.ndarray], structures: list[SubmodelStructure], h: float,
                       controller: DiscreteController, delay: int = 0) -> float:
    """Spectral radius of the noise-free closed loop of the model and ``C_d`` (< 1: stabilized)."""
    plant = total_model_discrete(thetas, structures, h)
    return spectral_radius(closed_loop_matrix(plant, controller, delay))


def closed_loop_response(thetas: list[np.ndarray], structures: list[SubmodelStructure], h: float,
                         controller: DiscreteController, r: np.ndarray, delay: int = 0,
                         check: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Noise-free closed loop of the current model: ``z = S_uo(q) r`` and ``T_o(q) r`` ([A-SRIVC] eq. 20).

    ``S_uo = C_d / (1 + C_d G_d)`` (erratum 3 in docs/DESIGN.md) with ``G_d`` the ZOH equivalent of the whole
    additive model including the input delay of ``delay`` samples. Raises
    :class:`ClosedLoopUnstableError` when ``check`` and the controller does not stabilize the model.
    Returns ``(z, y_cl)``: controller output (the plant input before the delay) and model output.
    """
    plant = total_model_discrete(thetas, structures, h)
    if check:
        rho = spectral_radius(closed_loop_matrix(plant, controller, delay))
        if not rho < 1.0:
            raise ClosedLoopUnstableError(
                f"the controller does not stabilize the model (closed-loop spectral radius {rho:.6g} >= 1)")
    cnum, cden = _controller_arrays(controller)
    r = np.ascontiguousarray(r, dtype=float)
    return _closed_loop_loop(np.ascontiguousarray(plant.phi), np.ascontiguousarray(plant.gamma),
                             np.ascontiguousarray(plant.c[0]), float(plant.d[0]), int(delay), cnum, cden, r)
