"""Streaming recursive additive SRIVC / CLSRIVC estimator ([RA-SRIVC] Algorithm 2, §4.5-4.7).

:class:`RecursiveAdditiveSRIVC` wraps the compiled kernel (:mod:`.kernel`) with a robust start (the offline
additive (CL)SRIVC, [A-SRIVC] eqs. 20-29, on the first data, then filter priming, Algorithm 2 step 1), a streaming
API (:meth:`~RecursiveAdditiveSRIVC.update` takes any number of samples; ``thetas``, ``covariances``, ``modal``,
``health``), snapshot and restore (all state in numpy arrays: a restored estimator continues bit-identically) and
bad-input handling (a non-finite or masked sample is skipped and counted, a gap re-primes the filters; theta and P
never become non-finite). Forgetting is per *update*: ``lambda_i = 1 - subsampling / (memory_s_i * rate)``, so the
memory in seconds depends neither on the rate nor on the subsampling. Submodels: second-order modes
``b0/(a2 p^2 + a1 p + 1)`` and rigid bodies ``b0/p^l``, l = 1, 2 (§4.6 eqs. 34-35). Its parts: the state arrays
(:mod:`.recursive_state`), the start (:mod:`.recursive_start`), the reported numbers (:mod:`.recursive_report`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Literal, overload

import numpy as np

from ..model import SubmodelStructure
from ..params import EstimatorOptions, core_param
from . import kernel as kn
from . import recursive_state as rs
from .estimator import EstimatorHealth, MonitorSettings
from .free_response_restart import EXTEND, FreeResponseRestart
from .free_response_restart import STATE_KEY as RESTART_KEY
from .recursive_report import (  # noqa: F401 - re-exported: the estimator's public names
    COVARIANCE_REL_TOL,
    ReportCache,
    closed_loop_matrix,
    closed_loop_spectral_radius,
    covariance_problem,
    estimator_health,
    residual_variance,
)
from .recursive_start import OfflineStart, p0_from_information, sandwich_from_offline  # noqa: F401 - re-exported
from .recursive_state import STATE_KEYS, STATE_VERSION, p0_diagonal, stationary_sandwich  # noqa: F401 - re-exported

FILTER_PERIODS = 1.0  # default filter-model time constant in periods of each mode (set_filter_memory)
# "auto" filter policy: smooth the prefilter denominator of a mode only where the slow-variation approximation of
# [RA-SRIVC] Remark 4.4 fails, i.e. where the forgetting memory is shorter than this many decay times 1/(zeta omega)
AUTO_DECAY_FACTOR = 3.0
FILTER_POLICIES = core_param("estimator.filter_smoothing").choices  # ("auto", "on", "off")
P0_POLICIES = core_param("estimator.p0_policy").choices  # ("information", "relative")
DEFAULTS = EstimatorOptions()  # the estimator.* defaults (core/params.py) of the keyword arguments below


def auto_filter_memory(s: dict[str, np.ndarray], rate_hz: float) -> np.ndarray:
    """Filter-model time constants of the ``"auto"`` policy (``RecursiveAdditiveSRIVC.set_filter_policy``): one
    period of a mode whose forgetting memory is shorter than ``AUTO_DECAY_FACTOR`` decay times ``2 a2/a1``, where
    [RA-SRIVC] Remark 4.4 fails; 0 (Algorithm 2 as printed) for the others."""
    th, lam, kind = s["theta"], s["lam"], s["kind"]
    sub = int(s["cfg_i"][kn.C_SUBSAMPLE])
    K = int(s["cfg_i"][kn.C_K])
    tau = np.zeros(K)
    for i in range(K):
        a1, a2 = th[i, 0], th[i, 1]
        if kind[i] != 0 or not (a1 > 0.0 and a2 > 0.0) or lam[i] >= 1.0:
            continue
        memory_s = sub / ((1.0 - lam[i]) * rate_hz)
        if memory_s < AUTO_DECAY_FACTOR * 2.0 * a2 / a1:
            tau[i] = FILTER_PERIODS * 2.0 * math.pi * math.sqrt(a2)
    return tau


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
    constants), cut short by ``fit_free_response`` after a gap (:mod:`.free_response_restart`).
    """

    def __init__(self, structures: Sequence[SubmodelStructure], theta0: Sequence[np.ndarray], rate_hz: float, *,
                 forgetting: np.ndarray | Sequence[float] | float, controller: Any,
                 input_delay: int = 0, block_sweeps: int = DEFAULTS.block_sweeps,
                 refinements: int = DEFAULTS.refinements, projection: bool = DEFAULTS.stability_projection,
                 subsampling: int = DEFAULTS.output_subsampling,
                 p0_relative: tuple[float, float] = (DEFAULTS.p0_relative_a, DEFAULTS.p0_relative_b),
                 max_step: float = 0.0, p_cap: float = math.inf, filter_memory_s: float | Sequence[float] | None = 0.0,
                 filter_policy: str | None = None,
                 reprime_s: float | None = None, fit_free_response: bool = True,
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
        kind = np.array([rs.kind_of(s) for s in structures], dtype=np.int64)
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
        self._report = ReportCache()
        self._filter_policy: str | None = None
        self._filter_memory_auto = False
        self._restart: FreeResponseRestart | None = None    # a collection after a break (free_response_restart)
        self.fit_free_response = bool(fit_free_response)
        theta = rs.initial_thetas(structures, theta0, kind)
        hold_len = rs.hold_length(theta, kind, self.rate_hz, reprime_s)
        self._s = rs.new_state(kind, theta, self.rate_hz, controller, input_delay=int(input_delay),
                               block_sweeps=block_sweeps, refinements=refinements, projection=projection,
                               subsampling=subsampling, hold_len=hold_len, max_step=max_step, p_cap=p_cap)
        self.set_forgetting(forgetting)
        self.set_filter_memory(filter_memory_s)
        if filter_policy is not None:
            self.set_filter_policy(filter_policy)
        rs.reset_covariance(self._s, self.p0_relative)
        rs.refresh_filters(self._s)
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
        structures = [rs.structure_of(k) for k in kind]
        theta = np.asarray(state["theta"], dtype=float)
        theta0 = [theta[i, :s.n_theta] for i, s in enumerate(structures)]
        controller = None
        if cfg_i[kn.C_CLOSED]:
            from ..controller import DiscreteController  # lazy: scipy.signal is slow to import
            controller = DiscreteController(tuple(np.asarray(state["cnum"])), tuple(np.asarray(state["cden"])))
        est = cls(structures, theta0, 1.0 / cfg_f[kn.C_H], forgetting=np.asarray(state["lam"]), controller=controller,
                  input_delay=int(cfg_i[kn.C_DELAY]), block_sweeps=int(cfg_i[kn.C_SWEEPS]),
                  refinements=int(cfg_i[kn.C_REFINE]), projection=bool(cfg_i[kn.C_PROJ]),
                  subsampling=int(cfg_i[kn.C_SUBSAMPLE]), max_step=float(cfg_f[kn.C_MAXSTEP]),
                  p_cap=float(cfg_f[kn.C_PCAP]), filter_memory_s=0.0)
        # the filter model's factors muf are restored by set_state (stored per mode, not as a time constant)
        est.set_state(state)
        return est

    # ------------------------------------------------------------------ properties
    @property
    def K(self) -> int:
        return int(self._s["cfg_i"][kn.C_K])

    @property
    def closed_loop(self) -> bool:
        return bool(self._s["cfg_i"][kn.C_CLOSED])

    @property
    def arrays(self) -> dict[str, np.ndarray]:
        """The kernel's state arrays themselves (not copies; :mod:`.recursive_state` describes them)."""
        return self._s

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
        return residual_variance(self._s)

    # ------------------------------------------------------------------ reported numbers (recursive_report.py)
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
        return [c.copy() for c in self._report.blocks(self._s, self.structures).covariances]

    @property
    def information_covariances(self) -> list[np.ndarray]:
        """``sigma^2 P_bar_i`` (the adaptation gain's scale, [RA-SRIVC] §4.2): it winds up without excitation, the
        sandwich :attr:`covariances` does not (an estimate that stops moving keeps its error), so loss of excitation is
        judged on this one."""
        return [c.copy() for c in self._report.blocks(self._s, self.structures).information]

    def covariance_problems(self) -> list[str]:
        """Per mode ``""`` or why its covariance block gives no std: ``"non-finite"`` or ``"indefinite"`` (smallest
        eigenvalue below ``-1e-9`` times the largest magnitude). Such a mode reports NaN std, never 0."""
        return list(self._report.blocks(self._s, self.structures).problems)

    def modal(self) -> np.ndarray:
        """(K, 6): ``f_hz, zeta, gain, f_std, zeta_std, gain_std`` (delta method, model.modal_std, on the IV sandwich
        :attr:`covariances`). A mode whose covariance block is non-finite or indefinite reports NaN std (see
        :meth:`covariance_problems` and ``health.covariance_problems``)."""
        return self._report.blocks(self._s, self.structures).modal.copy()

    def information_relative_std(self) -> np.ndarray:
        """Per mode the largest relative std of (f, gain) from :attr:`information_covariances` (loss of excitation:
        ``P_bar`` winds up); NaN for a mode whose information block is non-finite or indefinite."""
        return self._report.blocks(self._s, self.structures).information_relative_std.copy()

    def iv_condition(self) -> np.ndarray:
        """Condition number per mode of the equilibrated IV matrix ``D R D`` (``R = P^-1``, ``D = |theta|``): infinite
        when singular, NaN when not finite."""
        return self._report.blocks(self._s, self.structures).iv_condition.copy()

    def closed_loop_max_pole(self) -> float:
        """Largest closed-loop pole modulus of the current model with ``C_d`` and the input delay (NaN in open loop).

        ``>= 1``: the model's noise-free closed loop, which also generates the instrument ([RA-SRIVC] eq. 33), is
        unstable; the estimate is then no valid model of a plant that the controller stabilizes.
        """
        if not self.closed_loop or self.controller is None:
            return math.nan
        return closed_loop_spectral_radius(self._s["kind"], self.thetas, self.rate_hz, self.controller,
                                           int(self._s["cfg_i"][kn.C_DELAY]))

    @property
    def health(self) -> EstimatorHealth:
        """Samples, updates, skipped/held samples, re-primes, projections and rejections per mode (total and per
        reason, core/estimation/kernel.py "Safeguards"), non-finite instrument samples, IV condition numbers,
        residual variance."""
        return estimator_health(self._s, self._report.blocks(self._s, self.structures), self.init_message)

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
        if self._filter_policy == "auto":
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
        policy = self._filter_policy
        if policy is None:
            return
        if policy == "off":
            self.set_filter_memory(0.0)
        elif policy == "on":
            self.set_filter_memory(None)
        else:
            self.set_filter_memory(auto_filter_memory(self._s, self.rate_hz))
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

    # ------------------------------------------------------------------ data (the kernel, core/estimation/kernel.py)
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
        r, u, y, v = rs.sample_arrays(r, u, y, valid, self.closed_loop)
        tr = np.empty((u.size if trace else 0, self.K, kn.NT))
        a = 0
        while self._restart is not None and a < u.size:   # the first samples after a break: collected, no updates
            b = a + min(self._restart.missing, u.size - a)
            self._run(r[a:b], u[a:b], y[a:b], v[a:b], True, tr[a:b])
            self._collect(r[a:b], u[a:b], y[a:b], v[a:b])
            a = b
        self._run(r[a:], u[a:], y[a:], v[a:], True, tr[a:])
        return tr if trace else None

    def _collect(self, r: np.ndarray, u: np.ndarray, y: np.ndarray, v: np.ndarray) -> None:
        restart = self._restart
        assert restart is not None
        restart.add(r, u, y, v)
        restart.keep_residual_level(self._s)   # the free response is no residual noise (health reads this level)
        if restart.missing == 0 and restart.apply(self._s) != EXTEND:
            self._restart = None        # applied, or the full hold runs on

    def prime(self, r: Any, u: Any, y: Any, valid: Any = None) -> None:
        """[RA-SRIVC] Algorithm 2 step 1: filters from rest over the data with the current model, no updates."""
        r, u, y, v = rs.sample_arrays(r, u, y, valid, self.closed_loop)
        self._reset_filters()
        self._run(r, u, y, v, False, np.empty((0, self.K, kn.NT)))

    def _reset_filters(self) -> None:
        """Filters, delay line and controller memory from rest (:func:`.recursive_state.reset_filters`)."""
        rs.reset_filters(self._s)
        self._restart = None

    def mark_gap(self) -> None:
        """Data are missing: restart the filters from rest and hold updates for the re-prime length, or until the
        plant's free response is fitted (``fit_free_response``: :mod:`.free_response_restart`)."""
        self._reset_filters()
        s = self._s
        s["ist"][kn.I_HOLD] = max(int(s["ist"][kn.I_HOLD]), int(s["cfg_i"][kn.C_HOLDLEN]))
        s["ist"][kn.I_REPRIMES] += 1
        if self.fit_free_response:
            self._restart = FreeResponseRestart.begin(s, self.rate_hz)

    def reset(self, theta0: Sequence[np.ndarray] | None = None) -> None:
        """Restart the recursion: theta (given or current), P(0), filters from rest; counters kept."""
        if theta0 is not None:
            for i, th in enumerate(theta0):
                self._s["theta"][i, :np.size(th)] = np.asarray(th, dtype=float)
        self._s["thf"][...] = self._s["theta"]
        if self._filter_policy is not None:
            self._apply_filter_policy()
        elif self._filter_memory_auto:
            self.set_filter_memory(None)
        rs.reset_covariance(self._s, self.p0_relative)
        rs.refresh_filters(self._s)
        self._reset_filters()

    def output_error_variance(self, thetas: Sequence[np.ndarray], r: np.ndarray, u: np.ndarray, y: np.ndarray,
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
        """Robust start ([A-SRIVC] offline fit, the guesses as a prior, ``P(0)``, priming: :class:`.recursive_start.
        OfflineStart`). Returns the ``IdentificationResult`` or ``None`` (no offline core, ``init_method="none"`` or
        failure); ``init_message`` says what was used."""
        return OfflineStart(self).run(r, u, y)

    # ------------------------------------------------------------------ snapshot / restore (recursive_state.py)
    def get_state(self) -> dict[str, np.ndarray]:
        """Complete state as a dict of numpy arrays (copies); see :meth:`set_state`."""
        state = rs.snapshot(self._s)
        state[RESTART_KEY] = np.zeros(0) if self._restart is None else self._restart.to_array()
        return state

    def set_state(self, state: Mapping[str, np.ndarray]) -> None:
        """Restore a :meth:`get_state` snapshot; continuation is bit-identical. Shapes must match.

        Version-1 snapshots (before the filter model) load with ``theta_f = theta`` and ``mu_f = 0``.
        """
        rs.restore(self._s, state)
        self._restart = FreeResponseRestart.from_array(np.asarray(state.get(RESTART_KEY, np.zeros(0))))

    def save(self, path: str | Path) -> None:
        """Write the state to an ``.npz`` file."""
        rs.save_state(path, self.get_state())

    def load(self, path: str | Path) -> None:
        """Restore the state written by :meth:`save` into this (identically configured) estimator."""
        self.set_state(rs.load_state(path))

    @classmethod
    def restore(cls, path: str | Path) -> RecursiveAdditiveSRIVC:
        """Build an estimator from a :meth:`save` file alone."""
        return cls.from_state(rs.load_state(path))
