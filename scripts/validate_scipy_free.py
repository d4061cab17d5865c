"""The two pieces that replace scipy on the diagnosis path, against scipy itself.

``python scripts/validate_scipy_free.py`` prints the largest relative difference of
``core.distributions.f_quantile`` from ``scipy.special.fdtri`` over probabilities 1e-6 .. 1 - 1e-6 and degrees of
freedom 0.5 .. 100000, and of ``core.matrix_exponential.expm`` from ``scipy.linalg.expm`` on the augmented ZOH
matrices of the offline instrument filters ([A-SRIVC] eqs. 10, 20, 31: modes 0.5-400 Hz, damping 0.002-0.7, gains 1e-4
to 1e4, at 20, 1000 and 4096 Hz) and on random matrices of 1-norm 1e-6 to 300.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import expm as scipy_expm
from scipy.special import fdtri

from additive_rsrivc_ros.core.distributions import f_quantile
from additive_rsrivc_ros.core.filters import instrument_continuous
from additive_rsrivc_ros.core.matrix_exponential import expm
from additive_rsrivc_ros.core.model import SubmodelStructure, theta_from_modal


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b, 1) / max(np.linalg.norm(b, 1), 1e-300))


def quantile_worst() -> tuple[float, tuple, int]:
    worst, where, n = 0.0, (), 0
    for d1 in (0.5, 1, 1.5, 2, 3, 4, 6, 8, 12, 20):
        for m in (1, 2, 5, 20, 100, 1000, 5000):
            for p in (1e-6, 1e-3, 0.1, 0.5, 0.9, 0.99, 0.999, 1 - 1e-4, 1 - 1e-6):
                ref = float(fdtri(d1, d1 * m, p))
                err = abs(f_quantile(float(d1), float(d1 * m), p) / ref - 1.0)
                n += 1
                if err > worst:
                    worst, where = err, (d1, d1 * m, p)
    return worst, where, n


def filter_expm_worst() -> tuple[float, int]:
    worst, n = 0.0, 0
    for rate in (20.0, 1000.0, 4096.0):
        for f in (0.5, 3.0, 33.0, 183.0, 400.0):
            if f > rate / 4:
                continue
            for zeta in (0.002, 0.05, 0.7):
                for gain in (1e-4, 1.0, 1e4):
                    a, b, _, _ = instrument_continuous(theta_from_modal(f, zeta, gain), SubmodelStructure())
                    k = a.shape[0]
                    aug = np.zeros((k + 1, k + 1))
                    aug[:k, :k], aug[:k, k] = a / rate, b / rate
                    worst = max(worst, _rel(expm(aug), scipy_expm(aug)))
                    n += 1
    return worst, n


def random_expm_worst(seed: int = 1) -> tuple[float, int]:
    rng = np.random.default_rng(seed)
    worst, n = 0.0, 0
    for scale in (1e-6, 1e-2, 0.2, 0.9, 2.0, 5.0, 30.0, 300.0):
        for size in (2, 3, 4, 6):
            for _ in range(25):
                a = rng.standard_normal((size, size))
                a *= scale / np.linalg.norm(a, 1)
                worst = max(worst, _rel(expm(a), scipy_expm(a)) / max(1.0, scale))
                n += 1
    return worst, n


def main() -> int:
    q, where, nq = quantile_worst()
    print(f"f_quantile vs scipy.special.fdtri: {nq} cases, largest relative difference {q:.2g} at (d1, d2, p) = "
          f"{where} (test tolerance 1e-9)")
    fe, nf = filter_expm_worst()
    print(f"expm vs scipy.linalg.expm on {nf} instrument-filter ZOH matrices: largest relative 1-norm difference "
          f"{fe:.2g}")
    re_, nr = random_expm_worst()
    print(f"expm vs scipy.linalg.expm on {nr} random matrices (1-norm 1e-6 to 300): largest relative 1-norm "
          f"difference / max(1, norm) {re_:.2g} (test tolerance 1e-12)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
