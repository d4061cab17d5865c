"""Each report's deviations from the baseline, and each mode's leading one (S3, S4).

The deviation of an estimate from its baseline is normalised by the std of their difference; it is relevant when it
exceeds the relevant change ``rho`` (the user's ``faults.min_change``, and well above the estimate's own healthy
spread). Under stress only a mode's leading deviation can be confirmed (:mod:`.faults`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .baseline import Baseline
from .fault_settings import FaultSettings


class Deviations(NamedTuple):
    """(K, 3) each: the deviation's std ``sigma`` (S3), the relevant change ``rho`` (relative), whether the deviation
    is relevant, and its significance score (``|dev| / sigma`` where relevant and applicable, else -1)."""

    sigma: np.ndarray
    rho: np.ndarray
    relevant: np.ndarray
    score: np.ndarray


def deviations(modal: np.ndarray, base: Baseline, settings: FaultSettings, applicable: np.ndarray) -> Deviations:
    """The deviations of the (K, >= 6) estimate ``modal`` from ``base``; ``applicable`` (K, 3) bool."""
    sx = np.fmax(modal[:, 3:6], base.spread)     # fmax: a NaN std (flagged covariance) falls back to the spread
    sigma = np.maximum(np.sqrt(sx * sx + base.std ** 2), 1e-9 * np.abs(base.value))
    with np.errstate(divide="ignore", invalid="ignore"):
        # relevant change: the user's minimum, and well above the estimate's own healthy fluctuation (a mode that
        # wanders by 1 % with the operating point must not alarm on a 2 % excursion)
        rho = np.maximum(np.asarray(settings.min_change)[None, :],
                         settings.relevance_spread_factor * base.spread / np.abs(base.value))
        rho = np.where(np.isfinite(rho), rho, np.asarray(settings.min_change)[None, :])
        dev = modal[:, :3] - base.value
        relevant = np.abs(dev) >= rho * np.abs(base.value)
        score = np.where(relevant, np.abs(dev) / sigma, -1.0)
    score = np.where(np.isfinite(score) & applicable, score, -1.0)
    return Deviations(sigma, rho, relevant, score)


def leads(score: np.ndarray, applicable: np.ndarray, faulted: np.ndarray) -> np.ndarray:
    """(K,) each mode's leading deviation: its confirmed fault (``faulted`` (K, 3) bool), else a relevant
    natural-frequency shift (it explains the damping and gain swings of the estimate while it re-converges: a
    lightly damped mode fitted at the old frequency looks broader; the converse does not hold), else its most
    significant relevant one."""
    lead = np.argmax(score, axis=1)
    for i in range(score.shape[0]):
        if applicable[i, 0] and score[i, 0] >= 0:
            lead[i] = 0
        if faulted[i].any():
            lead[i] = int(np.argmax(faulted[i]))
    return lead


PEAK_Z = 5.0   # a resonance-peak change this many (conservative, uncorrelated) stds from the baseline is significant


def peak_moved(modal: np.ndarray, base: Baseline, sigma: np.ndarray, min_change: float,
               applicable: np.ndarray) -> np.ndarray:
    """(K,) relative change of each mode's resonance peak ``gain / (2 damping)`` where it is relevant (at least
    ``min_change``, the gain's) and significant (``PEAK_Z`` stds, gain and damping stds ``sigma`` (K, 3) added in
    quadrature: their correlation only narrows it), else NaN. The recursion can split a peak change between damping
    and gain so that neither is relevant on its own (a -21 % gain step read as +18 % damping and -7 % gain)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        change = (modal[:, 2] / modal[:, 1]) / (base.value[:, 2] / base.value[:, 1]) - 1.0
        rel_std = np.hypot(sigma[:, 1] / np.abs(base.value[:, 1]), sigma[:, 2] / np.abs(base.value[:, 2]))
        moved = applicable[:, 1] & (np.abs(change) >= min_change) & (np.abs(change) >= PEAK_Z * rel_std)
    return np.where(moved & np.isfinite(change), change, np.nan)
