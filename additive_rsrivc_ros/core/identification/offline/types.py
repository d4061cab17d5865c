"""Data and results shared by the offline estimators (``stable`` and ``unstable``; [A-SRIVC], [BCD-SRIVC], [UNS-SRIVC]).

:class:`OfflineData` is the checked input of one identification, :class:`IdentificationResult` what every
estimator returns, :func:`equilibrated_solve` the equilibrated IV normal-equation solve they all use.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ...controller import DiscreteController
from ...model import SubmodelStructure

METHODS = ("auto", "additive-clsrivc", "additive-srivc", "bcd-srivc", "srivc", "clsrivc", "lssvf",
           "srivc-uns", "clsrivc-uns", "lssvf-uns", "srivc-uns-monic", "clsrivc-uns-monic")


@dataclass
class IdentificationResult:
    """Outcome of one offline estimator ([A-SRIVC] eq. 29 / Theorem 1 covariance).

    ``thetas``: per submodel, [RA-SRIVC] eq. 7 layout. ``covariance``: full ``sigma^2`` sandwich covariance
    ``sigma^2 M^-1 (Z^T Z) M^-T`` with ``M = Z^T Phi`` the IV normal matrix (asymptotically
    ``sigma^2 (sum zeta zeta^T)^-1``, [A-SRIVC] Theorem 1/Corollary 1); ``covariances`` its diagonal blocks.
    ``P``: the unscaled inverse IV normal matrix ``M^-1`` (sums, not means; [A-SRIVC] eq. 33), and ``p_blocks``
    the per-submodel ``(sum_k zeta_i phi_i^T)^-1`` used by the block-coordinate recursion ([RA-SRIVC] eqs. 30-32).
    ``cond``: condition number of the column-equilibrated IV normal matrix. ``cost``: ``V_N = mean(eps^2)``
    of the output error ([BCD-SRIVC] eq. 8). ``modal``: (K, 3) natural frequency [Hz], damping ratio, gain;
    ``modal_std`` by the delta method (``model.modal_std``).
    """

    method: str
    structures: list[SubmodelStructure]
    thetas: list[np.ndarray]
    covariances: list[np.ndarray]
    covariance: np.ndarray
    P: np.ndarray
    p_blocks: list[np.ndarray]
    residual_variance: float
    iterations: int
    converged: bool
    cond: float
    cost: float
    modal: np.ndarray
    modal_std: np.ndarray
    projections: int = 0
    message: str = ""
    n_samples: int = 0
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def beta(self) -> np.ndarray:
        """Stacked parameter vector ([RA-SRIVC] eq. 8)."""
        return np.concatenate(self.thetas)

    @property
    def theta_std(self) -> list[np.ndarray]:
        return [np.sqrt(np.maximum(np.diag(c), 0.0)) for c in self.covariances]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready object of docs/INTERFACE.md (``rsrivc_identify``)."""
        modes = []
        for th, sd, mo, ms in zip(self.thetas, self.theta_std, self.modal, self.modal_std, strict=True):
            modes.append({
                "theta": [float(v) for v in th], "theta_std": [float(v) for v in sd],
                "natural_frequency_hz": finite_or_none(mo[0]), "damping_ratio": finite_or_none(mo[1]),
                "gain": finite_or_none(mo[2]), "natural_frequency_hz_std": finite_or_none(ms[0]),
                "damping_ratio_std": finite_or_none(ms[1]), "gain_std": finite_or_none(ms[2]),
            })
        return {
            "method": self.method, "converged": bool(self.converged), "iterations": int(self.iterations),
            "modes": modes, "residual_variance": finite_or_none(self.residual_variance),
            "cost": finite_or_none(self.cost),
            "cond": finite_or_none(self.cond), "projections": int(self.projections), "message": self.message,
            "n_samples": int(self.n_samples),
        }


def finite_or_none(v: float) -> float | None:
    """``float(v)``, or None when it is not finite (JSON has no NaN)."""
    v = float(v)
    return v if np.isfinite(v) else None


@dataclass
class OfflineData:
    """The checked data of one identification: the delayed input, output, reference, sample time, loop."""

    u: np.ndarray          # input as seen by the plant (delayed)
    y: np.ndarray
    r: np.ndarray | None
    h: float
    controller: DiscreteController | None
    delay: int
    skip: int = 0          # filter warm-up samples left out of the normal equations and the cost
    free_response: bool = False  # the record starts in motion: the model's free response is projected out

    @property
    def closed_loop(self) -> bool:
        return self.r is not None and self.controller is not None

    def loop(self) -> tuple[DiscreteController, np.ndarray]:
        """``(controller, r)`` of closed-loop data; ``ValueError`` in open loop."""
        if self.controller is None or self.r is None:
            raise ValueError("closed-loop identification needs both the reference r and the controller")
        return self.controller, self.r

    @property
    def n(self) -> int:
        return self.y.size


def column_norms(a: np.ndarray) -> np.ndarray:
    """Euclidean norm of each column of a tall (N, p) matrix (one pass, no N x p temporaries: 3x faster than
    ``np.linalg.norm(a, axis=0)`` for the regressors of a long record)."""
    return np.sqrt(np.einsum("ij,ij->j", a, a))


def equilibrated_solve(M: np.ndarray, R: np.ndarray, zn: np.ndarray, pn: np.ndarray) -> tuple[np.ndarray, float]:
    """Solve ``M X = R`` after column/row equilibration; returns X and cond of the equilibrated matrix."""
    dz = 1.0 / np.where(zn > 0, zn, 1.0)
    dp = 1.0 / np.where(pn > 0, pn, 1.0)
    Ms = dz[:, None] * M * dp[None, :]
    cond = float(np.linalg.cond(Ms))
    if not np.isfinite(cond) or cond > 1e15:
        raise np.linalg.LinAlgError(f"IV normal matrix is singular (cond {cond:.3g})")
    X = dp[:, None] * np.linalg.solve(Ms, dz[:, None] * R)
    return X, cond
