"""Does a model fit the nonparametric FRF of its own data? The misfit statistic shared by the model-order check
(:mod:`.adequacy`) and the order scan of the automatic start (:mod:`.modefind`).

With ``var`` the FRF's complex variance (plus its resolution bias, :attr:`.frf.FRFEstimate.uncertainty`), the
normalized misfit ``z_k = |G_k - G_m,k|^2 / var_k`` of a complex Gaussian error is exponential with mean 1,
``P(z > t) = exp(-t)``; a bin misfits significantly when ``z_k > ln(n_bins / ALPHA)`` (Bonferroni over the bins).
"""

from __future__ import annotations

import math

import numpy as np

from .frf import FRFEstimate

ALPHA = 0.01
"""Probability that a model which fits (the FRF error is only noise) shows one significant misfit bin."""
START_SCREEN_FRACTION = 0.05
"""Share of misfit bins of an automatic start on its own window's FRF above which the whole check runs
(:func:`.adequacy.check_start`). Lower than :data:`.adequacy.MISFIT_FRACTION`: the check's refit can land elsewhere
(a rigid-body plant's wrong start misfit 5-15 % as found and 83 % refitted)."""
MIN_MISFIT_BINS = 5
"""... and at least this many bins (a short FRF has few)."""
MISFIT_RUN_BINS = 12
"""Consecutive compared FRF bins that misfit significantly, above which the model is flagged (state ``misfit``) even
when they are few of all the bins: a band the model misses, as two well-damped modes fitted as one broad lump (22 in
a row, 8 % of the bins: ``validate_autostart.py --seed 1``, plant 21). Measured: the 139 right automatic starts of the
four sets misfit at most 7 bins in a row on their own 20 s windows (0.49 Hz bins), the true models of the 60 random
plants at most 5 on 120 s windows (0.12 Hz bins); a bin misfits by chance with probability ``ALPHA / n``."""


def misfit(frf: FRFEstimate, G_model: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """``(z, usable, threshold)``: normalized misfit per bin, the valid leakage-free bins, and the Bonferroni
    threshold ``ln(n / ALPHA)`` of the exponential law of ``z`` (module docstring)."""
    usable = frf.valid & ~(frf.leakage if frf.leakage is not None else np.zeros(frf.valid.size, dtype=bool))
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.abs(frf.G - G_model) ** 2 / frf.uncertainty ** 2
    z = np.where(usable & np.isfinite(z), z, 0.0)
    n = int(usable.sum())
    return z, usable, math.log(max(n, 1) / ALPHA)


def longest_misfit_run(frf: FRFEstimate, z: np.ndarray, usable: np.ndarray,
                       threshold: float) -> tuple[int, float, float]:
    """The longest run of consecutive compared bins that misfit (``z > threshold``): ``(count, from Hz, to Hz)``."""
    idx = np.flatnonzero(usable)
    mis = np.concatenate(([False], z[idx] > threshold, [False])).astype(np.int8)
    starts, stops = np.flatnonzero(np.diff(mis) == 1), np.flatnonzero(np.diff(mis) == -1)
    if starts.size == 0:
        return 0, math.nan, math.nan
    j = int(np.argmax(stops - starts))
    f = frf.freqs_hz[idx]
    return int(stops[j] - starts[j]), float(f[starts[j]]), float(f[stops[j] - 1])


def fits_its_frf(frf: FRFEstimate, G_model: np.ndarray) -> bool:
    """The screen of a model (``G_model``: its FRF on the bins, :func:`.frf.model_frf_on_bins`) against the FRF of its
    own window (milliseconds): at most :data:`START_SCREEN_FRACTION` of the valid bins (at least
    :data:`MIN_MISFIT_BINS`) misfit significantly, fewer than :data:`MISFIT_RUN_BINS` of them in a row. Used by
    :func:`.adequacy.check_start` and by the order scan (:mod:`.modefind`: one mode more than a model that passes
    has nothing to fit but noise)."""
    z, usable, thr = misfit(frf, G_model)
    n_bins, n_mis = int(usable.sum()), int(np.sum(z > thr))
    return n_mis < max(MIN_MISFIT_BINS, START_SCREEN_FRACTION * n_bins) and \
        longest_misfit_run(frf, z, usable, thr)[0] < MISFIT_RUN_BINS
