"""What the recursive estimator reports from its state: covariances, stds, health numbers, closed-loop poles.

The IV sandwich covariance ``sigma^2 P_bar S P_bar^T`` and the information covariance ``sigma^2 P_bar`` ([RA-SRIVC]
§4.2, eqs. 30-32), the modal numbers and their stds (delta method), the IV condition numbers, computed once per state
(:class:`ReportCache` over :func:`.report_numbers.report_numbers`), the :class:`.estimator.EstimatorHealth` record, and
the poles of the model's noise-free closed loop that generates the instrument ([RA-SRIVC] eqs. 10, 33).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np

from ..model import SubmodelStructure
from . import kernel as kn
from .estimator import EstimatorHealth
from .report_numbers import PROBLEM_NAMES, block_problems, closed_loop_state_matrix, report_numbers

COVARIANCE_REL_TOL = 1e-9   # an eigenvalue below -this x the largest magnitude makes a covariance block indefinite


def covariance_problem(cov: np.ndarray, rel_tol: float = COVARIANCE_REL_TOL) -> str:
    """``""`` for a usable covariance block, else ``"non-finite"`` or ``"indefinite"`` (an eigenvalue below
    ``-rel_tol`` times the largest magnitude; ``sqrt(max(var, 0))`` would turn it into a silent std of 0). The
    rule is :func:`.report_numbers.block_problems`, which judges the per-report blocks."""
    cov = np.asarray(cov, dtype=float)
    return PROBLEM_NAMES[int(block_problems(cov.reshape(1, *cov.shape), rel_tol)[0])]


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


def residual_variance(s: dict[str, np.ndarray]) -> float:
    """Exponentially weighted mean of the squared output error ``y - sum_i x^_i`` (NaN before data)."""
    acc, w = s["fst"][kn.F_SIGACC], s["fst"][kn.F_SIGW]
    return float(acc / w) if w > 0.0 else float("nan")


class ReportBlocks(NamedTuple):
    """Per mode the sandwich and the information covariance blocks and their problems (``""`` when usable), and the
    published numbers computed from them (:func:`.report_numbers.report_numbers`)."""
    covariances: list[np.ndarray]
    problems: list[str]
    information: list[np.ndarray]
    information_problems: list[str]
    modal: np.ndarray                 # (K, 6) f_hz, zeta, gain and their stds
    information_relative_std: np.ndarray
    iv_condition: np.ndarray


class ReportCache:
    """The :class:`ReportBlocks` of the current state, computed once per state.

    Keyed on the bytes of every array they are computed from (``theta, P, S`` and the residual variance
    accumulator), so no change of state, by whatever path, can serve stale numbers."""

    def __init__(self) -> None:
        self._cached: tuple[bytes, ReportBlocks] | None = None

    def blocks(self, s: dict[str, np.ndarray], structures: Sequence[SubmodelStructure]) -> ReportBlocks:
        """The blocks and numbers for the state ``s`` (:func:`.report_numbers.report_numbers`)."""
        key = b"".join(s[k].tobytes() for k in ("theta", "P", "S", "fst"))
        cached = self._cached
        if cached is not None and cached[0] == key:
            return cached[1]
        K = int(s["cfg_i"][kn.C_K])
        cov, info = np.zeros((K, 3, 3)), np.zeros((K, 3, 3))
        problem, info_problem = np.zeros(K, dtype=np.int64), np.zeros(K, dtype=np.int64)
        modal, info_rel, cond = np.empty((K, 6)), np.empty(K), np.empty(K)
        report_numbers(s["kind"], s["theta"], s["P"], s["S"], float(residual_variance(s)), COVARIANCE_REL_TOL,
                       cov, info, problem, info_problem, modal, info_rel, cond)
        nts = [st.n_theta for st in structures]
        blocks = ReportBlocks([cov[i, :n, :n] for i, n in enumerate(nts)], [PROBLEM_NAMES[p] for p in problem],
                              [info[i, :n, :n] for i, n in enumerate(nts)], [PROBLEM_NAMES[p] for p in info_problem],
                              modal, info_rel, cond)
        self._cached = (key, blocks)
        return blocks


def estimator_health(s: dict[str, np.ndarray], blocks: ReportBlocks, init_message: str) -> EstimatorHealth:
    """Samples, updates, skipped/held samples, re-primes, projections and rejections per mode (total and per
    reason, core/estimation/kernel.py "Safeguards"), non-finite instrument samples, IV condition numbers, residual
    variance."""
    ist = s["ist"]
    return EstimatorHealth(
        samples=int(ist[kn.I_SAMPLES]),
        updates=int(ist[kn.I_UPDATES]),
        skipped_samples=int(ist[kn.I_SKIPPED]),
        held_samples=int(ist[kn.I_HELD]),
        hold_remaining=int(ist[kn.I_HOLD]),
        reprimes=int(ist[kn.I_REPRIMES]),
        capped_updates=int(ist[kn.I_CAPPED]),
        projections=tuple(int(v) for v in s["proj"]),
        rejected_updates=tuple(int(v) for v in s["rej"]),
        rejected_discretization=tuple(int(v) for v in s["rejr"][:, kn.R_DISC]),
        rejected_iv_denominator=tuple(int(v) for v in s["rejr"][:, kn.R_DEN]),
        rejected_nonfinite_or_step=tuple(int(v) for v in s["rejr"][:, kn.R_STEP]),
        nonfinite_instrument=int(ist[kn.I_NONFINITE_Z]),
        cond=tuple(float(v) for v in blocks.iv_condition),
        covariance_problems=tuple(blocks.problems),
        information_relative_std=tuple(float(v) for v in blocks.information_relative_std),
        residual_var=residual_variance(s),
        init_message=init_message,
    )
