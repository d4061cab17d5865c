"""Streaming recursive additive SRIVC / CLSRIVC estimator ([RA-SRIVC] Algorithm 2, §4.5-4.7).

:class:`RecursiveAdditiveSRIVC` wraps the compiled kernel (:mod:`.kernel`) with a robust start (the offline
additive (CL)SRIVC, [A-SRIVC] eqs. 20-29, on the first data, then filter priming, Algorithm 2 step 1), a streaming
API (:meth:`~RecursiveAdditiveSRIVC.update` takes any number of samples; ``thetas``, ``covariances``, ``modal``,
``health``), snapshot and restore (all state in numpy arrays: a restored estimator continues bit-identically) and
bad-input handling (a non-finite or masked sample is skipped and counted, a gap re-primes the filters; theta and P
never become non-finite). Forgetting is per *update*: ``lambda_i = 1 - subsampling / (memory_s_i * rate)``, so the
memory in seconds depends neither on the rate nor on the subsampling. Submodels: second-order modes
``b0/(a2 p^2 + a1 p + 1)`` and rigid bodies ``b0/p^l``, l = 1, 2 (§4.6 eqs. 34-35).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Literal, NamedTuple, overload

import numpy as np

from . import kernel as kn
from .estimator import EstimatorHealth, MonitorSettings
from .model import SubmodelStructure, modal_from_theta, theta_from_modal
from .params import EstimatorOptions, core_param
from .report_numbers import PROBLEM_NAMES, block_problems, closed_loop_state_matrix, report_numbers

STATE_KEYS = ("kind", "lam", "muf", "cnum", "cden", "cfg_i", "cfg_f", "p0diag", "theta", "thf", "P", "S", "xs", "vin",
              "phi",
              "gam", "ubuf", "zbuf", "ce", "cz", "ist", "fst", "proj", "rej", "rejr")
_INT_KEYS = ("kind", "cfg_i", "ist", "proj", "rej", "rejr")
# 2: filter model "thf", "muf"; version-1 snapshots load with thf = theta, muf = 0 (Algorithm 2)
# 3: rejections per reason "rejr" and the non-finite instrument counter in "ist"; older snapshots load with zeros
# 4: IV sandwich accumulator "S"; older snapshots load with S = P^-1 / (1 + lambda) (stationary)
# 5: a rigid body's free response c0, c1 in slots 1, 2 of theta, P, S; older snapshots start it
#    unknown
STATE_VERSION = 5
FILTER_PERIODS = 1.0  # default filter-model time constant in periods of each mode (set_filter_memory)
# "auto" filter policy: smooth the prefilter denominator of a mode only where the slow-variation approximation of
# [RA-SRIVC] Remark 4.4 fails, i.e. where the forgetting memory is shorter than this many decay times 1/(zeta omega)
AUTO_DECAY_FACTOR = 3.0
FILTER_POLICIES = core_param("estimator.filter_smoothing").choices  # ("auto", "on", "off")


def _kind_of(s: SubmodelStructure) -> int:
    """Kernel mode kind: 0 = second-order mode, l = rigid body ``b0/p^l``."""
    if s.n == 2 and s.m == 0 and s.integrators == 0:
        return 0
    if s.n == 0 and s.m == 0 and s.integrators in (1, 2):
        return s.integrators
    raise ValueError(f"unsupported submodel {s}: the recursive engine supports b0/(a2 p^2 + a1 p + 1) "
                     "and rigid-body b0/p^l (l = 1, 2)")


def _structure_of(kind: int) -> SubmodelStructure:
    return SubmodelStructure(2, 0, 0) if kind == 0 else SubmodelStructure(0, 0, int(kind))


P0_POLICIES = core_param("estimator.p0_policy").choices  # ("information", "relative")
DEFAULTS = EstimatorOptions()  # the estimator.* defaults (core/params.py) of the keyword arguments below


def p0_from_information(p_block: np.ndarray, n_samples: int, lam: float) -> np.ndarray | None:
    """``P_i(0)`` from an offline fit: its ``(sum_k zeta_i phi_i^T)^-1`` over ``n_samples`` samples ([A-SRIVC] eq. 33)
    rescaled to the exponential weighting of the recursion ([RA-SRIVC] eqs. 30-32, ``P^-1 <- lambda P^-1 + zeta
    phi^T``): the record's per-sample information times ``sum_k lambda^k = (1 - lambda^N)/(1 - lambda)``, i.e.
    ``P_i(0) = N (1 - lambda) / (1 - lambda^N) * p_block``. ``None`` if the block is not usable (non-finite or
    a non-positive diagonal)."""
    p = np.asarray(p_block, dtype=float)
    if n_samples < 1 or not np.all(np.isfinite(p)) or np.any(np.diag(p) <= 0.0) or not 0.0 < lam < 1.0:
        return None
    weight = n_samples * (1.0 - lam) / (1.0 - lam ** n_samples)
    return weight * p


def p0_diagonal(theta: np.ndarray, kind: int, p0_relative: tuple[float, float]) -> np.ndarray:
    """``P_i(0)`` diagonal scaled with the parameters: ``rho_a^2 a_j^2`` and ``rho_b^2 b0^2``."""
    ra, rb = p0_relative
    out = np.zeros(kn.NT)
    th = np.abs(np.asarray(theta, dtype=float))
    th = np.maximum(th, 1e-300)
    if kind == 0:
        out[:3] = [ra * th[0] ** 2, ra * th[1] ** 2, rb * th[2] ** 2]
    else:
        out[0] = rb * th[0] ** 2
        out[1:1 + kind] = kn.P0_FREE   # the free response c0 (, c1): core/kernel.py free_response_step
    return out


COVARIANCE_REL_TOL = 1e-9   # an eigenvalue below -this x the largest magnitude makes a covariance block indefinite


def covariance_problem(cov: np.ndarray, rel_tol: float = COVARIANCE_REL_TOL) -> str:
    """``""`` for a usable covariance block, else ``"non-finite"`` or ``"indefinite"`` (an eigenvalue below
    ``-rel_tol`` times the largest magnitude; ``sqrt(max(var, 0))`` would turn it into a silent std of 0). The
    rule is :func:`.report_numbers.block_problems`, which judges the per-report blocks."""
    cov = np.asarray(cov, dtype=float)
    return PROBLEM_NAMES[int(block_problems(cov.reshape(1, *cov.shape), rel_tol)[0])]


def stationary_sandwich(p: np.ndarray, lam: float) -> np.ndarray:
    """``S`` that makes ``P S P^T = P/(1 + lam)``: ``S = P^-1/(1 + lam)`` (symmetrized). For stationary signals
    ``P ~ (1 - lam) Rbar^-1`` and ``S ~ Rbar/(1 - lam^2)`` (``RecursiveAdditiveSRIVC.covariances``), so this is the
    sandwich of an estimator already in its stationary regime: the start of the accumulator when ``P(0)`` is not
    an information (parameter-scaled diagonal) or a snapshot predates it. Zeros if ``P`` is not invertible."""
    p = np.asarray(p, dtype=float)
    try:
        s = np.linalg.inv(p) / (1.0 + lam)
    except np.linalg.LinAlgError:
        return np.zeros_like(p)
    if not np.all(np.isfinite(s)):
        return np.zeros_like(p)
    return 0.5 * (s + s.T)


def sandwich_from_offline(p0: np.ndarray, cov0: np.ndarray, sigma2_0: float) -> np.ndarray | None:
    """``S_i(0) = P_i(0)^-1 C_0 P_i(0)^-T / sigma_0^2``: the recursion starts at the offline estimate, whose error
    covariance ``C_0`` is the offline IV sandwich ([A-SRIVC] Theorem 1, its block of the joint matrix, so the coupling
    of the modes in the start record is in it); with it ``sigma^2 P S P^T`` equals ``C_0`` at the start and the
    ``lam^(2N) S(0)`` term forgets it like the recursion forgets ``theta_bar(0)``. ``None`` if not usable."""
    try:
        pinv = np.linalg.inv(np.asarray(p0, dtype=float))
    except np.linalg.LinAlgError:
        return None
    c0 = np.asarray(cov0, dtype=float)
    if not (np.isfinite(sigma2_0) and sigma2_0 > 0.0) or c0.shape != pinv.shape:
        return None
    s = pinv @ c0 @ pinv.T / sigma2_0
    s = 0.5 * (s + s.T)
    if not np.all(np.isfinite(s)) or covariance_problem(s):
        return None
    return s


def closed_loop_matrix(kinds: Sequence[int] | np.ndarray, thetas: Sequence[np.ndarray], rate_hz: float, controller: Any,
                       input_delay: int = 0) -> np.ndarray:
    """State matrix of the noise-free sampled loop ``u = C_d(q)(r - y)`` about the frozen ZOH model ([RA-SRIVC] eq. 10).

    The same loop generates the closed-loop instrument ``z = S_uo r`` ([RA-SRIVC] eq. 33, erratum 3 in docs/DESIGN.md):
    when it is unstable the instrument and its filters grow without bound and the recursion cannot run. Per mode the
    kernel's own ZOH discretization of ``1/A_i`` (or ``1/p^l``) with output ``b0 w``; ``d`` input-delay shift states
    (``x_{k+1} = Phi x_k + Gamma u_{k-d}``); ``C_d`` in transposed direct form II (``scipy.signal.lfilter``).
    """
    kind = np.asarray(kinds, dtype=np.int64)
    theta = np.zeros((kind.size, kn.NT))
    for i, th in enumerate(thetas):
        th = np.asarray(th, dtype=float).ravel()
        theta[i, :th.size] = th
    num, den = np.asarray(controller.num, float), np.asarray(controller.den, float)
    nc = max(num.size, den.size) - 1
    nump, denp = np.zeros(nc + 1), np.zeros(nc + 1)
    nump[:num.size], denp[:den.size] = num / den[0], den / den[0]
    nx = int(sum(2 if k == 0 else k for k in kind))
    n = nx + int(input_delay) + nc
    a = np.zeros((n, n))
    closed_loop_state_matrix(kind, theta, 1.0 / rate_hz, int(input_delay), nump, denp, a)
    return a


def closed_loop_spectral_radius(kinds: Sequence[int] | np.ndarray, thetas: Sequence[np.ndarray], rate_hz: float,
                                controller: Any, input_delay: int = 0) -> float:
    """Largest modulus of the poles of :func:`closed_loop_matrix` (NaN if the model is not finite)."""
    if not all(np.all(np.isfinite(np.asarray(t, float))) for t in thetas):
        return math.nan
    a = closed_loop_matrix(kinds, thetas, rate_hz, controller, input_delay)
    if not np.all(np.isfinite(a)):
        return math.nan
    return float(np.max(np.abs(np.linalg.eigvals(a)))) if a.size else 0.0


class _ReportBlocks(NamedTuple):
    """Per mode the sandwich and the information covariance blocks and their problems (``""`` when usable), and the
    published numbers computed from them (:func:`.report_numbers.report_numbers`)."""
    covariances: list[np.ndarray]
    problems: list[str]
    information: list[np.ndarray]
    information_problems: list[str]
    modal: np.ndarray                 # (K, 6) f_hz, zeta, gain and their stds
    information_relative_std: np.ndarray
    iv_condition: np.ndarray


class RecursiveAdditiveSRIVC:
    """Recursive additive (CL)SRIVC estimator, [RA-SRIVC] Algorithm 2 with the closed-loop instrument eq. 33.

    ``structures, theta0``: submodels and their ``[a1, a2, b0]`` (rigid body ``[b0]``); ``forgetting``: ``lambda_i`` per
    mode and update; ``controller``: ``C_d`` of the instrument ``z = S_uo(q, t_k) r`` (None: open loop, ``z = u``, eq.
    28); ``input_delay`` in samples; ``block_sweeps, refinements``: ``M_l, M_s``; ``projection`` and ``subsampling``:
    §4.7. ``p0_*``, ``init_*``, ``guess_spread`` and ``filter_policy`` mean what the ``estimator.*`` parameters of
    :mod:`.params` say. ``p0_policy`` ``"information"`` starts ``P_i(0)`` at the offline fit's information weighted like
    the recursion (:func:`p0_from_information`), else the diagonal of ``p0_relative``; ``max_step`` (0: off) and
    ``p_cap`` (inf: off) guard parameter steps and wind-up; ``filter_memory_s`` (or ``filter_policy``) sets the filter
    model ``a_f <- mu_f a_f + (1 - mu_f) a`` that builds the prefilters (0: Algorithm 2 as printed; ``None``:
    ``FILTER_PERIODS`` periods of the mode, needed when a memory is below the mode's decay time; ``inf``: fixed
    prefilters); ``reprime_s``: seconds without updates after a gap or a filter reset (default: 5 slowest time
    constants).
    """

    def __init__(self, structures: Sequence[SubmodelStructure], theta0: Sequence[np.ndarray], rate_hz: float, *,
                 forgetting: np.ndarray | Sequence[float] | float, controller: Any,
                 input_delay: int = 0, block_sweeps: int = DEFAULTS.block_sweeps,
                 refinements: int = DEFAULTS.refinements, projection: bool = DEFAULTS.stability_projection,
                 subsampling: int = DEFAULTS.output_subsampling,
                 p0_relative: tuple[float, float] = (DEFAULTS.p0_relative_a, DEFAULTS.p0_relative_b),
                 max_step: float = 0.0, p_cap: float = math.inf, filter_memory_s: float | Sequence[float] | None = 0.0,
                 filter_policy: str | None = None,
                 reprime_s: float | None = None,
                 init_method: str = DEFAULTS.init_method, init_max_iterations: int = DEFAULTS.init_max_iterations,
                 init_samples: int | None = None, init_warmup_s: float | None = None,
                 p0_policy: str = DEFAULTS.p0_policy, guess_spread: float = DEFAULTS.guess_spread) -> None:
        structures = list(structures)
        K = len(structures)
        if K == 0:
            raise ValueError("at least one submodel is needed")
        if len(theta0) != K:
            raise ValueError(f"{len(theta0)} initial parameter vectors for {K} submodels")
        if not rate_hz > 0.0:
            raise ValueError(f"rate_hz must be > 0, got {rate_hz}")
        if int(input_delay) < 0 or int(block_sweeps) < 1 or int(refinements) < 0 or int(subsampling) < 1:
            raise ValueError("need input_delay >= 0, block_sweeps >= 1, refinements >= 0, subsampling >= 1")
        kind = np.array([_kind_of(s) for s in structures], dtype=np.int64)
        if np.sum(kind > 0) > 1:
            raise ValueError("at most one rigid-body submodel ([RA-SRIVC] §4.6)")
        self.structures = structures
        self.rate_hz = float(rate_hz)
        self.p0_relative = (float(p0_relative[0]), float(p0_relative[1]))
        if p0_policy not in P0_POLICIES:
            raise ValueError(f"p0_policy must be one of {', '.join(P0_POLICIES)}, got {p0_policy!r}")
        self.p0_policy = p0_policy
        self.init_method = init_method
        self.init_max_iterations = int(init_max_iterations)
        self.init_samples = init_samples
        self.init_warmup_s = init_warmup_s
        if not (math.isfinite(guess_spread) and guess_spread >= 0.0):
            raise ValueError(f"guess_spread must be >= 0, got {guess_spread}")
        self.guess_spread = float(guess_spread)
        self.controller = controller
        self.last_init: Any = None
        self.init_message = "not initialized"
        h = 1.0 / self.rate_hz

        theta = np.zeros((K, kn.NT))
        for i, (th, st) in enumerate(zip(theta0, structures, strict=True)):
            th = np.asarray(th, dtype=float).ravel()
            if th.shape != (st.n_theta,) or not np.all(np.isfinite(th)):
                raise ValueError(f"theta0[{i}] must be {st.n_theta} finite values, got {th}")
            if kind[i] == 0:
                a1, a2, flag = kn.project_second_order(th[0], th[1])
                if a2 == 0.0:
                    raise ValueError(f"theta0[{i}]: a2 must be non-zero")
                th = np.array([a1, a2, th[2]])
            theta[i, :th.size] = th
        if reprime_s is None:
            taus = [2.0 * theta[i, 1] / theta[i, 0] for i in range(K) if kind[i] == 0 and theta[i, 0] > 0]
            reprime_s = 5.0 * max(taus) if taus else 1.0
        hold_len = int(min(max(math.ceil(reprime_s * self.rate_hz), 10), 600 * self.rate_hz))

        if controller is not None:
            cnum, cden = controller.num.astype(float), controller.den.astype(float)
        else:
            cnum, cden = np.zeros(1), np.ones(1)
        d = int(input_delay)
        s: dict[str, np.ndarray] = {
            "kind": kind,
            "lam": np.zeros(K),
            "muf": np.zeros(K),
            "cnum": np.ascontiguousarray(cnum),
            "cden": np.ascontiguousarray(cden),
            "cfg_i": np.array([K, d, int(block_sweeps), int(refinements), int(bool(projection)), int(subsampling),
                               int(controller is not None), hold_len], dtype=np.int64),
            "cfg_f": np.array([h, 0.0, float(max_step), float(p_cap), 0.0]),
            "p0diag": np.zeros((K, kn.NT)),
            "theta": theta,
            "thf": theta.copy(),
            "P": np.zeros((K, kn.NT, kn.NT)),
            "S": np.zeros((K, kn.NT, kn.NT)),
            "xs": np.zeros((K, kn.N_BANKS, 2)),
            "vin": np.zeros((K, 2)),
            "phi": np.zeros((K, 2, 2)),
            "gam": np.zeros((K, 2)),
            "ubuf": np.zeros(d + 1),
            "zbuf": np.zeros(d + 1),
            "ce": np.zeros(max(cnum.size - 1, 1)),
            "cz": np.zeros(max(cden.size - 1, 1)),
            "ist": np.zeros(kn.N_IST, dtype=np.int64),
            "fst": np.zeros(kn.N_FST),
            "proj": np.zeros(K, dtype=np.int64),
            "rej": np.zeros(K, dtype=np.int64),
            "rejr": np.zeros((K, kn.N_REJ), dtype=np.int64),
        }
        self._s = s
        self.set_forgetting(forgetting)
        self.set_filter_memory(filter_memory_s)
        if filter_policy is not None:
            self.set_filter_policy(filter_policy)
        self._reset_covariance()
        self._refresh_filters()

    # ------------------------------------------------------------------ construction helpers
    @classmethod
    def from_config(cls, cfg: MonitorSettings) -> RecursiveAdditiveSRIVC:
        """Build from a :class:`config.MonitorConfig` (modes, memories, controller, ``cfg.estimator`` options)."""
        if not cfg.modes:  # without guesses the modes come from core.modefind.autostart_config first
            raise ValueError("no mode guesses (modes.natural_frequency_hz empty): find them first (core.modefind."
                             "autostart_config, rsrivc_diagnose, or rsrivc_identify --modes auto --out-params)")
        est = cfg.estimator
        sub = int(est.output_subsampling)
        lam = np.array([1.0 - sub / (m.memory_s * cfg.loop_rate_hz) for m in cfg.modes])
        return cls(cfg.structures, [m.theta0() for m in cfg.modes], cfg.loop_rate_hz, forgetting=lam,
                   controller=cfg.controller if cfg.closed_loop else None, input_delay=cfg.input_delay_samples,
                   block_sweeps=est.block_sweeps, refinements=est.refinements, projection=est.stability_projection,
                   subsampling=sub, p0_relative=(est.p0_relative_a, est.p0_relative_b),
                   init_method=est.init_method, init_max_iterations=est.init_max_iterations,
                   init_samples=int(round(cfg.init_duration_s * cfg.loop_rate_hz)),
                   init_warmup_s=None if est.init_warmup_s < 0 else est.init_warmup_s,
                   filter_policy=est.filter_smoothing, p0_policy=est.p0_policy, guess_spread=est.guess_spread)

    @classmethod
    def from_state(cls, state: dict[str, np.ndarray]) -> RecursiveAdditiveSRIVC:
        """Rebuild an estimator from a :meth:`get_state` snapshot alone (structures, rate, controller...)."""
        kind = np.asarray(state["kind"]).astype(np.int64)
        cfg_i = np.asarray(state["cfg_i"]).astype(np.int64)
        cfg_f = np.asarray(state["cfg_f"], dtype=float)
        structures = [_structure_of(k) for k in kind]
        theta = np.asarray(state["theta"], dtype=float)
        theta0 = [theta[i, :s.n_theta] for i, s in enumerate(structures)]
        controller = None
        if cfg_i[kn.C_CLOSED]:
            from .controller import DiscreteController  # lazy: scipy.signal is slow to import
            controller = DiscreteController(tuple(np.asarray(state["cnum"])), tuple(np.asarray(state["cden"])))
        est = cls(structures, theta0, 1.0 / cfg_f[kn.C_H], forgetting=np.asarray(state["lam"]), controller=controller,
                  input_delay=int(cfg_i[kn.C_DELAY]), block_sweeps=int(cfg_i[kn.C_SWEEPS]),
                  refinements=int(cfg_i[kn.C_REFINE]), projection=bool(cfg_i[kn.C_PROJ]),
                  subsampling=int(cfg_i[kn.C_SUBSAMPLE]), max_step=float(cfg_f[kn.C_MAXSTEP]),
                  p_cap=float(cfg_f[kn.C_PCAP]), filter_memory_s=0.0)
        # the filter model's factors muf are restored by set_state (stored per mode, not as a time constant)
        est.set_state(state)
        return est

    def _reset_covariance(self) -> None:
        s = self._s
        for i in range(self.K):
            diag = p0_diagonal(s["theta"][i], int(s["kind"][i]), self.p0_relative)
            s["p0diag"][i] = diag
            s["P"][i] = np.diag(diag)
            nt = kn.n_kernel_params(int(s["kind"][i]))
            s["S"][i] = 0.0
            s["S"][i][:nt, :nt] = stationary_sandwich(s["P"][i][:nt, :nt], float(s["lam"][i]))

    def _refresh_filters(self) -> None:
        """Cache ``Phi, Gamma`` of the current filter model (the kernel keeps them in step afterwards)."""
        s = self._s
        h = float(s["cfg_f"][kn.C_H])
        for i in range(self.K):
            th = s["thf"][i]
            kn.discretize_mode(int(s["kind"][i]), float(th[0]), float(th[1]), h, s["phi"][i], s["gam"][i])

    def _reset_filters(self) -> None:
        """Filters, delay line and controller memory from rest (before priming); a rigid body's free response is
        unknown again (core/kernel.py ``restart_free_response``)."""
        s = self._s
        for key in ("xs", "vin", "ubuf", "zbuf", "ce", "cz"):
            s[key][...] = 0.0
        s["ist"][kn.I_POS] = 0
        kn.restart_free_response(s["kind"], s["theta"], s["thf"], s["P"], s["S"], s["p0diag"])

    # ------------------------------------------------------------------ properties
    @property
    def K(self) -> int:
        return int(self._s["cfg_i"][kn.C_K])

    @property
    def closed_loop(self) -> bool:
        return bool(self._s["cfg_i"][kn.C_CLOSED])

    @property
    def forgetting(self) -> np.ndarray:
        return self._s["lam"].copy()

    @property
    def thetas(self) -> list[np.ndarray]:
        """Latest ``theta_bar_i(t_k)`` per mode ([RA-SRIVC] eq. 7 order)."""
        return [self._s["theta"][i, :s.n_theta].copy() for i, s in enumerate(self.structures)]

    @property
    def residual_variance(self) -> float:
        """Exponentially weighted mean of the squared output error ``y - sum_i x^_i`` (NaN before data)."""
        acc, w = self._s["fst"][kn.F_SIGACC], self._s["fst"][kn.F_SIGW]
        return float(acc / w) if w > 0.0 else float("nan")

    @property
    def covariances(self) -> list[np.ndarray]:
        """Covariance of ``theta_bar_i`` per mode: the IV sandwich ``sigma^2 P_bar_i S_i P_bar_i^T``.

        Linearizing [RA-SRIVC] eqs. 30-32, ``theta_bar - theta = P_bar sum_k lam^(N-k) zeta_k v_k`` (``v`` white,
        variance ``sigma^2``), so ``Cov = sigma^2 P_bar S P_bar^T`` with ``S = sum_k lam^(2(N-k)) zeta zeta^T +
        lam^(2N) S(0)`` (kernel accumulator). For stationary signals ``Cov ~ sigma^2 P_bar/(1 + lam)``: the
        "approximate covariance" ``sigma^2 P_bar`` of §4.2 overstates the std by ``sqrt 2``. No cross-mode term: the
        block-coordinate recursion's stationary error covariance is ``sigma^2 G/2`` with the block-diagonal gain
        ``G`` (first order in ``1 - lam``); the offline start's coupled covariance enters through ``S(0)``.
        """
        return [c.copy() for c in self._blocks().covariances]

    def _blocks(self) -> _ReportBlocks:
        """:attr:`covariances`, :attr:`information_covariances`, their problems and the numbers a report publishes
        (:meth:`modal`, :meth:`information_relative_std`, :meth:`iv_condition`) for the current state, computed once
        per state (:func:`.report_numbers.report_numbers`): a report asks for them through
        :meth:`modal` and :attr:`health`. The cache is keyed on the bytes of every array they are computed from
        (``theta, P, S`` and the residual variance accumulator), so no change of state, by whatever path, can serve
        stale numbers."""
        st = self._s
        key = b"".join(st[k].tobytes() for k in ("theta", "P", "S", "fst"))
        cached = getattr(self, "_blocks_cache", None)
        if cached is not None and cached[0] == key:
            return cached[1]
        K = self.K
        cov, info = np.zeros((K, 3, 3)), np.zeros((K, 3, 3))
        problem, info_problem = np.zeros(K, dtype=np.int64), np.zeros(K, dtype=np.int64)
        modal, info_rel, cond = np.empty((K, 6)), np.empty(K), np.empty(K)
        report_numbers(st["kind"], st["theta"], st["P"], st["S"], float(self.residual_variance), COVARIANCE_REL_TOL,
                       cov, info, problem, info_problem, modal, info_rel, cond)
        nts = [s.n_theta for s in self.structures]
        blocks = _ReportBlocks([cov[i, :n, :n] for i, n in enumerate(nts)], [PROBLEM_NAMES[p] for p in problem],
                               [info[i, :n, :n] for i, n in enumerate(nts)], [PROBLEM_NAMES[p] for p in info_problem],
                               modal, info_rel, cond)
        self._blocks_cache = (key, blocks)
        return blocks

    @property
    def information_covariances(self) -> list[np.ndarray]:
        """``sigma^2 P_bar_i`` (the adaptation gain's scale, [RA-SRIVC] §4.2): it winds up without excitation, the
        sandwich :attr:`covariances` does not (an estimate that stops moving keeps its error), so loss of excitation is
        judged on this one."""
        return [c.copy() for c in self._blocks().information]

    def covariance_problems(self) -> list[str]:
        """Per mode ``""`` or why its covariance block gives no std: ``"non-finite"`` or ``"indefinite"`` (smallest
        eigenvalue below ``-1e-9`` times the largest magnitude). Such a mode reports NaN std, never 0."""
        return list(self._blocks().problems)

    def modal(self) -> np.ndarray:
        """(K, 6): ``f_hz, zeta, gain, f_std, zeta_std, gain_std`` (delta method, model.modal_std, on the IV sandwich
        :attr:`covariances`). A mode whose covariance block is non-finite or indefinite reports NaN std (see
        :meth:`covariance_problems` and ``health.covariance_problems``)."""
        return self._blocks().modal.copy()

    def information_relative_std(self) -> np.ndarray:
        """Per mode the largest relative std of (f, gain) from :attr:`information_covariances` (loss of excitation:
        ``P_bar`` winds up); NaN for a mode whose information block is non-finite or indefinite."""
        return self._blocks().information_relative_std.copy()

    def closed_loop_max_pole(self) -> float:
        """Largest closed-loop pole modulus of the current model with ``C_d`` and the input delay (NaN in open loop).

        ``>= 1``: the model's noise-free closed loop, which also generates the instrument ([RA-SRIVC] eq. 33), is
        unstable; the estimate is then no valid model of a plant that the controller stabilizes.
        """
        if not self.closed_loop or self.controller is None:
            return math.nan
        return closed_loop_spectral_radius(self._s["kind"], self.thetas, self.rate_hz, self.controller,
                                           int(self._s["cfg_i"][kn.C_DELAY]))

    def iv_condition(self) -> np.ndarray:
        """Condition number per mode of the equilibrated IV matrix ``D R D`` (``R = P^-1``, ``D = |theta|``): infinite
        when singular, NaN when not finite."""
        return self._blocks().iv_condition.copy()

    @property
    def health(self) -> EstimatorHealth:
        """Samples, updates, skipped/held samples, re-primes, projections and rejections per mode (total and per
        reason, core/kernel.py "Safeguards"), non-finite instrument samples, IV condition numbers, residual variance."""
        ist = self._s["ist"]
        return EstimatorHealth(
            samples=int(ist[kn.I_SAMPLES]),
            updates=int(ist[kn.I_UPDATES]),
            skipped_samples=int(ist[kn.I_SKIPPED]),
            held_samples=int(ist[kn.I_HELD]),
            hold_remaining=int(ist[kn.I_HOLD]),
            reprimes=int(ist[kn.I_REPRIMES]),
            capped_updates=int(ist[kn.I_CAPPED]),
            projections=tuple(int(v) for v in self._s["proj"]),
            rejected_updates=tuple(int(v) for v in self._s["rej"]),
            rejected_discretization=tuple(int(v) for v in self._s["rejr"][:, kn.R_DISC]),
            rejected_iv_denominator=tuple(int(v) for v in self._s["rejr"][:, kn.R_DEN]),
            rejected_nonfinite_or_step=tuple(int(v) for v in self._s["rejr"][:, kn.R_STEP]),
            nonfinite_instrument=int(ist[kn.I_NONFINITE_Z]),
            cond=tuple(float(v) for v in self.iv_condition()),
            covariance_problems=tuple(self.covariance_problems()),
            information_relative_std=tuple(float(v) for v in self.information_relative_std()),
            residual_var=self.residual_variance,
            init_message=self.init_message,
        )

    # ------------------------------------------------------------------ runtime changes
    def set_forgetting(self, forgetting: np.ndarray | Sequence[float] | float) -> None:
        """Set ``lambda_i`` (per update) at run time; scalar = the same for all modes."""
        lam = np.broadcast_to(np.asarray(forgetting, dtype=float), (self.K,)).copy()
        if not np.all((lam > 0.0) & (lam <= 1.0)):
            raise ValueError(f"forgetting factors must be in (0, 1], got {lam}")
        self._s["lam"][:] = lam
        # residual variance: exponential memory of the slowest mode, per sample
        sub = int(self._s["cfg_i"][kn.C_SUBSAMPLE])
        self._s["cfg_f"][kn.C_LAMSIG] = 1.0 - (1.0 - float(lam.max())) / sub
        if getattr(self, "_filter_policy", None) == "auto":
            self._apply_filter_policy()

    def set_filter_policy(self, policy: str) -> None:
        """Choose when the prefilters use the smoothed filter model ``A_f`` (see :meth:`set_filter_memory`).

        ``"off"``: [RA-SRIVC] Algorithm 2 as printed. ``"on"``: every mode, one period of the mode. ``"auto"``: only the
        modes whose forgetting memory is shorter than ``AUTO_DECAY_FACTOR`` decay times ``1/(zeta omega) =
        2 a2/a1`` of their current model, where the slow-variation approximation of [RA-SRIVC] Remark 4.4 behind the
        carried filter states fails (the estimate <-> prefilter loop then oscillates and grows; measured in
        ``scripts/study_short_memory.py``). Re-evaluated on :meth:`reset`, :meth:`initialize` and memory changes.
        """
        if policy not in FILTER_POLICIES:
            raise ValueError(f"filter policy must be one of {', '.join(FILTER_POLICIES)}, got {policy!r}")
        self._filter_policy = policy
        self._apply_filter_policy()

    def _apply_filter_policy(self) -> None:
        policy = getattr(self, "_filter_policy", None)
        if policy is None:
            return
        if policy == "off":
            self.set_filter_memory(0.0)
        elif policy == "on":
            self.set_filter_memory(None)
        else:
            th, lam, kind = self._s["theta"], self._s["lam"], self._s["kind"]
            sub = int(self._s["cfg_i"][kn.C_SUBSAMPLE])
            tau = np.zeros(self.K)
            for i in range(self.K):
                a1, a2 = th[i, 0], th[i, 1]
                if kind[i] != 0 or not (a1 > 0.0 and a2 > 0.0) or lam[i] >= 1.0:
                    continue
                memory_s = sub / ((1.0 - lam[i]) * self.rate_hz)
                if memory_s < AUTO_DECAY_FACTOR * 2.0 * a2 / a1:
                    tau[i] = FILTER_PERIODS * 2.0 * math.pi * math.sqrt(a2)
            self.set_filter_memory(tau)
        self._filter_policy = policy

    def set_filter_memory(self, filter_memory_s: float | Sequence[float] | np.ndarray | None) -> None:
        """Time constant (s) of the filter model ``A_f,i`` per mode; ``None`` = ``FILTER_PERIODS`` periods.

        [RA-SRIVC] Remark 4.4 carries the filter states across coefficient changes, which is exact only while the
        coefficients are nearly constant over the filters' response. With a memory shorter than the decay time
        ``1/(zeta omega)`` of a lightly damped mode the estimate <-> prefilter loop of Algorithm 2 (through
        ``A_i`` alone) oscillates and grows (``scripts/study_short_memory.py``); averaging the estimated ``A_i``
        over a few periods of the mode before it builds the filters breaks that loop. The fixed point is
        unchanged (``A_f = A`` when the estimate is stationary). 0 = Algorithm 2, ``inf`` = frozen filters.
        Rigid-body modes have no ``A`` ([RA-SRIVC] §4.6) and ignore it.
        """
        K = self.K
        sub = int(self._s["cfg_i"][kn.C_SUBSAMPLE])
        if filter_memory_s is None:
            self._filter_memory_auto = True
            th = self._s["theta"]
            tau = np.array([FILTER_PERIODS * 2.0 * math.pi * math.sqrt(th[i, 1]) if self._s["kind"][i] == 0
                            and th[i, 1] > 0.0 else 0.0 for i in range(K)])
        else:
            self._filter_memory_auto = False
            tau = np.broadcast_to(np.asarray(filter_memory_s, dtype=float), (K,)).copy()
        if not np.all(tau >= 0.0):
            raise ValueError(f"filter_memory_s must be >= 0, got {filter_memory_s}")
        mu = np.zeros(K)
        for i in range(K):
            if math.isinf(tau[i]):
                mu[i] = 1.0
            elif tau[i] > 0.0:
                mu[i] = max(0.0, 1.0 - sub / (tau[i] * self.rate_hz))
        self._s["muf"][:] = mu

    @property
    def filter_memory_s(self) -> np.ndarray:
        """Filter-model time constant per mode in s (0: Algorithm 2, inf: frozen filters)."""
        mu = self._s["muf"]
        sub = int(self._s["cfg_i"][kn.C_SUBSAMPLE])
        with np.errstate(divide="ignore"):
            return np.where(mu == 0.0, 0.0, sub / ((1.0 - mu) * self.rate_hz))

    @property
    def filter_thetas(self) -> list[np.ndarray]:
        """``[a_f1, a_f2, b0]`` of the filter model per mode (equal to :attr:`thetas` with ``filter_memory_s = 0``)."""
        return [self._s["thf"][i, :s.n_theta].copy() for i, s in enumerate(self.structures)]

    def set_memory(self, memory_s: np.ndarray | Sequence[float] | float) -> None:
        """``lambda_i = 1 - subsampling/(memory_s_i rate)`` (lambda scales with the rate)."""
        mem = np.broadcast_to(np.asarray(memory_s, dtype=float), (self.K,))
        sub = int(self._s["cfg_i"][kn.C_SUBSAMPLE])
        if not np.all(mem * self.rate_hz >= 2.0 * sub):
            raise ValueError(f"memory_s must cover at least two updates, got {mem}")
        self.set_forgetting(1.0 - sub / (mem * self.rate_hz))

    # ------------------------------------------------------------------ data
    def _arrays(self, r: Any, u: Any, y: Any, valid: Any) -> tuple[np.ndarray, ...]:
        u = np.ascontiguousarray(np.atleast_1d(np.asarray(u, dtype=float)).ravel())
        y = np.ascontiguousarray(np.atleast_1d(np.asarray(y, dtype=float)).ravel())
        n = u.size
        if y.size != n:
            raise ValueError(f"u and y must have the same length, got {n} and {y.size}")
        if r is None:
            if self.closed_loop:
                raise ValueError("closed loop: the reference r is needed for the instrument ([RA-SRIVC] eq. 33)")
            r = np.zeros(n)
        r = np.ascontiguousarray(np.atleast_1d(np.asarray(r, dtype=float)).ravel())
        if r.size != n:
            raise ValueError(f"r must have the same length as u, got {r.size} and {n}")
        if valid is None:
            v = np.ones(n, dtype=np.uint8)
        else:
            v = np.ascontiguousarray(np.broadcast_to(np.asarray(valid, dtype=bool), (n,)).astype(np.uint8))
        return r, u, y, v

    def _run(self, r: np.ndarray, u: np.ndarray, y: np.ndarray, valid: np.ndarray, allow_update: bool,
             trace: np.ndarray) -> None:
        s = self._s
        kn.run_block(r, u, y, valid, allow_update, s["kind"], s["lam"], s["muf"], s["cnum"], s["cden"], s["cfg_i"],
                     s["cfg_f"], s["p0diag"], s["theta"], s["thf"], s["P"], s["S"], s["xs"], s["vin"], s["phi"],
                     s["gam"], s["ubuf"], s["zbuf"], s["ce"], s["cz"], s["ist"], s["fst"], s["proj"], s["rej"],
                     s["rejr"], trace)

    @overload
    def update(self, r: Any, u: Any, y: Any, valid: Any = None, *, trace: Literal[True]) -> np.ndarray: ...
    @overload
    def update(self, r: Any, u: Any, y: Any, valid: Any = None, *, trace: bool = False) -> np.ndarray | None: ...

    def update(self, r: Any, u: Any, y: Any, valid: Any = None, *, trace: bool = False) -> np.ndarray | None:
        """Process any number of samples ([RA-SRIVC] Algorithm 2 lines 2-16 per sample).

        ``r`` is ignored in open loop (may be ``None``). ``valid`` (bool, broadcastable) marks samples to
        skip; non-finite samples are skipped as well. With ``trace=True`` returns theta after every
        sample, shape (n, K, 3) (rigid-body modes use column 0).
        """
        r, u, y, v = self._arrays(r, u, y, valid)
        tr = np.empty((u.size if trace else 0, self.K, kn.NT))
        self._run(r, u, y, v, True, tr)
        return tr if trace else None

    def prime(self, r: Any, u: Any, y: Any, valid: Any = None) -> None:
        """[RA-SRIVC] Algorithm 2 step 1: filters from rest over the data with the current model, no updates."""
        r, u, y, v = self._arrays(r, u, y, valid)
        self._reset_filters()
        self._run(r, u, y, v, False, np.empty((0, self.K, kn.NT)))

    def mark_gap(self) -> None:
        """Data are missing: restart the filters from rest and hold updates for the re-prime length."""
        self._reset_filters()
        s = self._s
        s["ist"][kn.I_HOLD] = max(int(s["ist"][kn.I_HOLD]), int(s["cfg_i"][kn.C_HOLDLEN]))
        s["ist"][kn.I_REPRIMES] += 1

    def reset(self, theta0: Sequence[np.ndarray] | None = None) -> None:
        """Restart the recursion: theta (given or current), P(0), filters from rest; counters kept."""
        if theta0 is not None:
            for i, th in enumerate(theta0):
                self._s["theta"][i, :np.size(th)] = np.asarray(th, dtype=float)
        self._s["thf"][...] = self._s["theta"]
        if getattr(self, "_filter_policy", None) is not None:
            self._apply_filter_policy()
        elif self._filter_memory_auto:
            self.set_filter_memory(None)
        self._reset_covariance()
        self._refresh_filters()
        self._reset_filters()

    def _output_error_var(self, thetas: Sequence[np.ndarray], r: np.ndarray, u: np.ndarray, y: np.ndarray,
                          v: np.ndarray, start: int = 0) -> float:
        """Mean squared output error of a candidate model on the data from sample ``start`` on (a primed copy, no
        updates; the samples before ``start`` only run the filters)."""
        probe = RecursiveAdditiveSRIVC.from_state(self.get_state())
        probe.reset(thetas)
        st = probe._s
        st["fst"][:] = 0.0
        none = np.empty((0, self.K, kn.NT))
        if start > 0:
            probe._run(r[:start], u[:start], y[:start], v[:start], False, none)
            st["fst"][kn.F_SIGACC] = st["fst"][kn.F_SIGW] = 0.0
        st["cfg_f"][kn.C_LAMSIG] = 1.0 - 1.0 / max(u.size - start, 1)
        probe._run(r[start:], u[start:], y[start:], v[start:], False, none)
        return probe.residual_variance

    def initialize(self, r: Any, u: Any, y: Any) -> Any:
        """Robust start: offline init, P(0) scaled per parameter, then priming.

        The offline estimate (``core.offline.identify``, [A-SRIVC] eqs. 20-29), combined with the guesses as a prior
        (:meth:`_with_guess_prior`), replaces the guesses only when it is finite, stable and explains the data better
        (smaller output-error variance). Returns the ``IdentificationResult`` or ``None`` (no offline core,
        ``init_method="none"`` or failure).
        """
        r, u, y, v = self._arrays(r, u, y, None)
        result = None
        accepted = False
        guesses = self.thetas
        if self.init_method != "none" and u.size > 0:
            try:
                from .offline import identify
            except ImportError:  # pragma: no cover - offline core not installed
                self.init_message = "offline core unavailable: using the guesses"
            else:
                def fit_once(r: np.ndarray, u: np.ndarray, y: np.ndarray) -> Any:
                    ok = np.isfinite(u) & np.isfinite(y) & (np.isfinite(r) if self.closed_loop else True)
                    return identify(u[ok], y[ok], self.rate_hz, self.structures, guesses,
                                    r=r[ok] if self.closed_loop else None, controller=self.controller,
                                    input_delay=int(self._s["cfg_i"][kn.C_DELAY]), method=self.init_method,
                                    max_iterations=self.init_max_iterations, warmup_s=self.init_warmup_s)
                try:
                    result = fit_once(r, u, y)
                except Exception as exc:  # noqa: BLE001 - any failure falls back to the guesses
                    self.init_message = f"offline init failed ({type(exc).__name__}: {exc}); using the guesses"
                    result = None
                if result is not None:
                    cand = [np.asarray(t, dtype=float) for t in result.thetas]
                    usable = all(np.all(np.isfinite(t)) for t in cand) and all(
                        t[0] > 0 and t[1] > 0 for t, k in zip(cand, self._s["kind"], strict=True) if k == 0)
                    if usable:
                        e_new = self._output_error_var(cand, r, u, y, v)
                        e_old = self._output_error_var(guesses, r, u, y, v)
                        if np.isfinite(e_new) and not e_new > e_old:
                            # the fit explains the data better: its posterior with the guesses is the start (between
                            # the two, so its error is judged through the fit's; in-sample it may be a hair worse)
                            cand, prior_note = self._with_guess_prior(guesses, cand, result, (r, u, y, v), fit_once)
                            e_post = self._output_error_var(cand, r, u, y, v) if prior_note else e_new
                            self.reset(cand)
                            accepted = True
                            self.init_message = (f"offline init ({getattr(result, 'message', '')}){prior_note}: "
                                                 f"output-error variance {e_old:.3g} -> {e_post:.3g} (fit {e_new:.3g})")
                        else:
                            self.init_message = f"offline init rejected (worse fit {e_new:.3g} > {e_old:.3g})"
                    else:
                        self.init_message = "offline init rejected (non-finite or unstable)"
        elif self.init_method == "none":
            self.init_message = "initialized with the guesses (init_method none)"
        self.reset(self.thetas)
        if accepted and self.p0_policy == "information":
            self._covariance_from_information(result)
        self._s["fst"][:] = 0.0
        self.prime(r, u, y, v)
        self.last_init = result
        return result

    HELD_OUT = 1.0 / 3.0   # the last third of the initialization window judges the guesses against the fit

    def _uninformed(self, guesses: list[np.ndarray], data: tuple[np.ndarray, ...], fit_once: Any,
                    ) -> set[tuple[int, int]]:
        """(mode, quantity) pairs the data do not inform: the guess predicts data *not used to fit* as well.

        The offline fit of the first two thirds of the window (``fit_once(r, u, y)``) predicts the last third by its
        output ``y_fit = sum_i G_i u`` (the models run over the whole window; a rigid body's free response is
        projected out). So does the same fit with one mode's shape (natural frequency and damping) put back to its
        guess, and with its gain put back: ``y_fit - delta``. The guess's squared error exceeds the fit's by
        ``mean(delta^2 + 2 e delta)`` with ``e = y - y_fit``, whose noise part has the std ``2 sigma rms(delta) /
        sqrt(n)``; the fit is preferred only when it predicts significantly better (2 stds). In-sample, a mode no
        reference line reaches can take any shape and still lower the error by fitting noise (measured: a 3.2 Hz mode
        fitted at 1.5 Hz with std 0.2 %), while its gain is informed by the lines below it (its static part).
        """
        from .offline import integrator_free_response
        from .plant import open_loop_output

        r, u, y, _ = data
        split = int(round(u.size * (1.0 - self.HELD_OUT)))
        if split < 10 or u.size - split < 10 or not np.all(np.isfinite(u)):
            return set()
        try:
            head = fit_once(r[:split], u[:split], y[:split])
        except Exception:  # noqa: BLE001 - no held-out judgement without a fit: the whole-window fit decides
            return set()
        fit = [np.asarray(t, dtype=float) for t in head.thetas]
        if not all(np.all(np.isfinite(t)) for t in fit):
            return set()
        delay = int(self._s["cfg_i"][kn.C_DELAY])
        ints = max(st.integrators for st in self.structures)
        basis = integrator_free_response(u.size, ints, 1.0 / self.rate_hz) if ints else None

        def detrended(x: np.ndarray) -> np.ndarray:
            return x if basis is None else x - basis @ (basis.T @ x)

        def output(thetas: list[np.ndarray]) -> np.ndarray:
            return detrended(open_loop_output(thetas, self.structures, self.rate_hz, u, delay))

        y_fit = output(fit)
        finite = np.isfinite(y)
        tail = (np.arange(u.size) >= split) & finite
        e = (detrended(np.where(finite, y, 0.0)) - y_fit)[tail]
        n = e.size
        if n < 10 or not np.all(np.isfinite(e)):
            return set()
        sigma = float(np.sqrt(np.mean(e * e)))
        out: set[tuple[int, int]] = set()
        for i, st in enumerate(self.structures):
            mg, mf = modal_from_theta(guesses[i], st), modal_from_theta(fit[i], st)
            parts = [((0, 1), (mg[0], mg[1], mf[2])), ((2,), (mf[0], mf[1], mg[2]))] if st.n == 2 else [((2,), None)]
            for qs, modal in parts:
                if modal is not None and not np.all(np.isfinite(modal)):
                    continue
                theta = guesses[i] if modal is None else theta_from_modal(*modal)
                delta = (y_fit - output([theta if k == i else f for k, f in enumerate(fit)]))[tail]
                if not np.all(np.isfinite(delta)):
                    continue
                worse = float(np.mean(delta * delta + 2.0 * e * delta))
                if worse <= 2.0 * 2.0 * sigma * float(np.sqrt(np.mean(delta * delta))) / np.sqrt(n):
                    out |= {(i, q) for q in qs}
        return out

    def _with_guess_prior(self, guesses: list[np.ndarray], fit: list[np.ndarray], result: Any,
                          data: tuple[np.ndarray, ...], fit_once: Any) -> tuple[list[np.ndarray], str]:
        """The offline fit combined with the guesses as a prior (guesses are a prior, not the answer).

        In modal coordinates ``m = (f, zeta, gain)`` per mode: prior ``N(m_g, diag((s m_g)^2))`` with ``s`` =
        ``guess_spread`` (a tiny spread for what :meth:`_uninformed` finds, and for a mode the fit leaves
        without a modal form), data ``N(m_f, C_f)`` with ``C_f`` the fit's joint covariance of every mode
        ([A-SRIVC] Theorem 1 sandwich, delta method); the start is the posterior mean ``m_g + P (P + C_f)^-1 (m_f -
        m_g)``: the fit where its data inform, the guesses where they do not, per mode (within a mode the covariance of
        gain and damping carries the other along the resonance peak). Only second-order modes and rigid bodies
        (their gain); otherwise the fit.
        Returns ``(thetas, note)``.
        """
        from .joint_check import joint_modal_covariance

        s = self.guess_spread
        sts = self.structures
        cov = getattr(result, "covariance", None)
        if s <= 0.0 or not all(st.m == 0 and st.n in (0, 2) for st in sts) or cov is None or \
                not np.all(np.isfinite(cov)):
            return fit, ""
        mf = np.array([modal_from_theta(t, st) for t, st in zip(fit, sts, strict=True)])
        mg = np.array([modal_from_theta(t, st) for t, st in zip(guesses, sts, strict=True)])
        app = np.array([[st.n == 2, st.n == 2, True] for st in sts])
        kept = self._uninformed(guesses, data, fit_once)
        kept |= {(i, q) for i in range(self.K) if not np.all(np.isfinite(mf[i][app[i]])) for q in range(3)}
        use = (app & np.isfinite(mg) & (mg != 0.0)).ravel()
        idx = np.flatnonzero(use)
        spread = np.array([1e-6 if (i, q) in kept else s for i in range(self.K) for q in range(3)])
        post = mg.ravel().copy()
        if idx.size:
            C = joint_modal_covariance(fit, sts, cov)[np.ix_(idx, idx)]
            lost = ~np.isfinite(np.diag(C)) | ~np.isfinite(mf.ravel()[idx])   # no modal form: the fit says nothing
            C[lost, :] = C[:, lost] = 0.0
            C[lost, lost] = (1e6 * mg.ravel()[idx][lost]) ** 2
            C = np.where(np.isfinite(C), C, 0.0)
            P = np.diag((spread[idx] * mg.ravel()[idx]) ** 2)
            d = np.where(np.isfinite(mf.ravel()[idx]), mf.ravel()[idx] - mg.ravel()[idx], 0.0)
            # per mode (its gain and damping trade along a resonance), not across modes: linear conditioning on a mode
            # the fit put far from its guess (a wrong optimum) moved the informed modes by more than their error
            # (measured: mode 1 by 6 %)
            mode_of = idx // 3
            for i in np.unique(mode_of):
                b = mode_of == i
                if (i, 0) in kept:       # the guessed shape predicted as well with the fit's gain: keep that pair
                    b &= idx % 3 == 2
                    post[idx[b]] = mg.ravel()[idx[b]] + np.diag(P)[b] / (np.diag(P)[b] + np.diag(C)[b]) * d[b]
                    continue
                try:
                    post[idx[b]] = mg.ravel()[idx[b]] + P[np.ix_(b, b)] @ np.linalg.solve(
                        P[np.ix_(b, b)] + C[np.ix_(b, b)], d[b])
                except np.linalg.LinAlgError:
                    return fit, ""
        post_modal = post.reshape(self.K, 3)
        if not np.all(np.isfinite(post_modal[app])) or np.any(post_modal[:, :2][app[:, :2]] <= 0.0):
            return fit, ""
        out = [np.array([post_modal[i, 2]]) if st.n == 0 else theta_from_modal(*post_modal[i])
               for i, st in enumerate(sts)]
        names = [f"mode {i + 1} {'shape' if q == 0 else 'gain'}" for i, q in sorted(kept) if q != 1 and app[i, q]]
        note = f"; guesses as a prior (spread {100 * s:g} %)" + (
            f", kept: {', '.join(names)} (the guess predicts held-out data as well)" if names else "")
        return out, note

    def _prior_p0(self, i: int, sigma2: float) -> np.ndarray | None:
        """``P_bar`` of mode ``i``'s guess as a prior (``guess_spread`` ``s``, relative, on f, zeta and gain alike):
        with ``a1 = 2 zeta / w``, ``a2 = 1/w^2``, ``b0 = g``, ``var ln a1 = 2 s^2``, ``var ln a2 = 4 s^2``,
        ``cov(ln a1, ln a2) = 2 s^2``, ``var ln b0 = s^2``, scaled by the coefficients and divided by ``sigma^2``
        (the recursion's covariance is ``sigma^2 P_bar``). None without a prior or a usable ``sigma^2``."""
        s, st = self.guess_spread, self.structures[i]
        if s <= 0.0 or not (np.isfinite(sigma2) and sigma2 > 0.0) or st.m != 0 or st.n not in (0, 2):
            return None
        th = np.abs(self._s["theta"][i, :st.n_theta])
        if st.n == 0:
            cov_ln = np.array([[1.0]])
        else:
            cov_ln = np.array([[2.0, 2.0, 0.0], [2.0, 4.0, 0.0], [0.0, 0.0, 1.0]])
        return s * s * cov_ln * np.outer(th, th) / sigma2

    def _covariance_from_information(self, result: Any) -> None:
        """``P_i(0)`` from the accepted offline fit (:func:`p0_from_information`), combined with the guesses' prior
        (:meth:`_prior_p0`: ``P^-1 = P_info^-1 + P_prior^-1``, so a mode the data hardly inform starts with the
        prior's adaptation gain, not an unbounded one); modes with neither keep the parameter-scaled diagonal."""
        s = self._s
        blocks = getattr(result, "p_blocks", None) or []
        n = int(getattr(result, "n_samples", 0))
        sigma2 = float(getattr(result, "residual_variance", math.nan))
        used = prior_used = 0
        for i, st in enumerate(self.structures):
            nt = st.n_theta
            p0 = p0_from_information(blocks[i], n, float(s["lam"][i])) if i < len(blocks) else None
            if p0 is not None and p0.shape != (nt, nt):
                p0 = None
            prior = self._prior_p0(i, sigma2)
            if prior is not None:
                try:
                    p0 = prior if p0 is None else np.linalg.inv(np.linalg.inv(p0) + np.linalg.inv(prior))
                    prior_used += 1
                except np.linalg.LinAlgError:
                    pass
            if p0 is None or not np.all(np.isfinite(p0)):
                continue
            p0 = 0.5 * (p0 + p0.T)
            s["P"][i][...] = 0.0
            s["P"][i][:nt, :nt] = p0
            s["p0diag"][i][...] = 0.0
            s["p0diag"][i][:nt] = np.diag(p0)
            covs = getattr(result, "covariances", None) or []
            s0 = sandwich_from_offline(p0, covs[i], sigma2) if i < len(covs) and prior is None else None
            s["S"][i][...] = 0.0
            s["S"][i][:nt, :nt] = s0 if s0 is not None else stationary_sandwich(p0, float(s["lam"][i]))
            used += 1
        self.init_message += f"; P(0) from the offline information for {used} of {self.K} modes" + (
            f" (with the guesses' prior for {prior_used})" if prior_used else "")

    # ------------------------------------------------------------------ snapshot / restore
    def get_state(self) -> dict[str, np.ndarray]:
        """Complete state as a dict of numpy arrays (copies); see :meth:`set_state`."""
        out = {k: self._s[k].copy() for k in STATE_KEYS}
        out["version"] = np.array([STATE_VERSION], dtype=np.int64)
        return out

    def set_state(self, state: Mapping[str, np.ndarray]) -> None:
        """Restore a :meth:`get_state` snapshot; continuation is bit-identical. Shapes must match.

        Version-1 snapshots (before the filter model) load with ``theta_f = theta`` and ``mu_f = 0``.
        """
        state = dict(state)
        if "thf" not in state and "theta" in state:
            state["thf"] = np.asarray(state["theta"], dtype=float).copy()
        if "muf" not in state and "lam" in state:
            state["muf"] = np.zeros(np.asarray(state["lam"]).shape)
        if "S" not in state and "P" in state:   # version <= 3: no IV sandwich accumulator, start it stationary
            lam = np.broadcast_to(np.asarray(state.get("lam", self._s["lam"]), dtype=float), (self.K,))
            state["S"] = np.zeros(np.asarray(state["P"]).shape)
            for i, p in enumerate(np.asarray(state["P"], dtype=float)):
                nt = kn.NT if int(np.asarray(state["kind"])[i]) == 0 else 1
                state["S"][i][:nt, :nt] = stationary_sandwich(p[:nt, :nt], float(lam[i]))
        if "rejr" not in state:   # version <= 2: no per-reason counts, shorter int state
            state["rejr"] = np.zeros_like(self._s["rejr"])
        if "ist" in state and np.asarray(state["ist"]).shape[0] < kn.N_IST:
            state["ist"] = np.concatenate((np.asarray(state["ist"], dtype=np.int64),
                                           np.zeros(kn.N_IST - np.asarray(state["ist"]).shape[0], dtype=np.int64)))
        for k in STATE_KEYS:
            if k not in state:
                raise ValueError(f"state is missing '{k}'")
            a = np.asarray(state[k])
            if a.shape != self._s[k].shape:
                raise ValueError(f"state '{k}' has shape {a.shape}, this estimator needs {self._s[k].shape}")
        if not np.array_equal(np.asarray(state["kind"]), self._s["kind"]):
            raise ValueError("state was saved for different submodel structures")
        for k in STATE_KEYS:
            dtype = np.int64 if k in _INT_KEYS else np.float64
            self._s[k][...] = np.asarray(state[k], dtype=dtype)
        if int(np.asarray(state.get("version", [0])).ravel()[0]) < 5:   # no free response: estimate it from now on
            s = self._s
            kn.restart_free_response(s["kind"], s["theta"], s["thf"], s["P"], s["S"], s["p0diag"])

    def save(self, path: str | Path) -> None:
        """Write the state to an ``.npz`` file."""
        np.savez(Path(path), **self.get_state())  # type: ignore[arg-type]  # numpy>=2.1 stub: **kwds may fill allow_pickle

    def load(self, path: str | Path) -> None:
        """Restore the state written by :meth:`save` into this (identically configured) estimator."""
        with np.load(Path(path)) as z:
            self.set_state({k: z[k] for k in z.files})

    @classmethod
    def restore(cls, path: str | Path) -> RecursiveAdditiveSRIVC:
        """Build an estimator from a :meth:`save` file alone."""
        with np.load(Path(path)) as z:
            return cls.from_state({k: z[k] for k in z.files})
