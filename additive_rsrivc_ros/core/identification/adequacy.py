"""Is the model order high enough for what we report? The model-order check (health WARN, never a fault).

A mode too few biases the modelled ones and nothing in the recursion sees it; a deliberately reduced model (the beam's 2
of 4 modes, [RA-SRIVC] §6) misfits as much but its unmodelled modes move nothing. So the check is about relevance. On a
window the K modes are refitted by the offline additive (CL)SRIVC ([A-SRIVC] eq. 29) and compared with the nonparametric
FRF bin by bin (:mod:`.frf_misfit`): 0. a refit with one sample of input delay more or fewer that predicts significantly
better (:data:`DELAY_ERROR_RATIO`) flags the delay; 1.-3. the resonances of the residual FRF ``G - G_m`` that misfit
(:func:`.modefind.find_candidates`, at most :data:`MAX_CANDIDATES`) are refitted as mode K + 1, which is real when it
lowers the output-error cost ([BCD-SRIVC] eq. 8), lies in the valid band and its gain is :data:`N_SIGMA` stds from zero
([A-SRIVC] Theorem 1); 4. more than :data:`MISFIT_FRACTION` of the bins (or :data:`MISFIT_RUN_BINS` in a row) misfitting
with no real extra mode, or an estimate that misfits where its refit does not, is state ``misfit``; 5. a real extra mode
that moves a modelled quantity by more than ``relevance x faults.min_change`` and ``N_SIGMA`` stds is state ``too_low``.
:class:`ModelOrderCheck` runs it once per run in the pipeline.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ..controller import DiscreteController
from ..model import SubmodelStructure, theta_from_modal
from ..vocabulary import MODEL_ORDER_FLAGGED, QUANTITIES, one_line
from .frf import FRFEstimate, estimate_frf, longest_finite, model_frf_on_bins
from .frf_misfit import (
    MIN_MISFIT_BINS,
    MISFIT_RUN_BINS,
    START_SCREEN_FRACTION,
    fits_its_frf,
    longest_misfit_run,
    misfit,
)
from .modefind import OrderRow, _held_out_error, _significant_gain, find_candidates

N_SIGMA = 3.0
"""Standard deviations an extra mode's gain, and a modelled quantity's change, must exceed."""
MISFIT_FRACTION = 0.15
"""Share of the compared FRF bins above which a significant misfit that no unmodelled resonance explains flags the
model (state ``misfit``). Measured (``validate_autostart.py``, 100 automatic starts: 40 from rest, 40 in motion, 20
with a rigid body): right starts misfit at most 7.2 % of their bins (a rigid-body plant's lowest bins), the 3 wrong
ones 47-86 %, a wrong start cut after a NaN burst 38 %; the true models of 15 random plants 0-3.6 %. (With the
lowest mode left out of the 14 with more than one, 7-98 %: 12 of them exceed this share, among them 6 of the 8 the
check had called adequate.)"""
MAX_CANDIDATES = 3
"""Unmodelled resonances refitted, largest misfit first (each refit costs one offline fit)."""
MIN_WINDOW_S = 2.0
"""Shortest contiguous stretch the check runs on (the FRF needs a few averages at a resolution below 1 Hz)."""
FIT_TOL = 1e-5
"""Relative parameter change that ends a check's refit: its moves are judged at >= 0.5 % (step 4)."""
QUANTITY_NAMES = ("natural frequency", "damping", "gain")
DELAY_ERROR_RATIO = 0.7
"""Step 0 (the input delay): a refit with one sample of input delay more or fewer whose simulated output error on the
window is below this fraction of the configured delay's, and significantly so throughout the window
(:func:`.modefind._significant_gain`: the paired test of the order scan), flags the configured delay (state
``misfit``). A whole sample is a large error: on 15 s of the bundled beam (K = 2 of 4, true delay 4 samples at 4096 Hz)
the held-out output error was 1.15e-7 at 4, 6.2e-7 and 7.1e-7 at 3 and 5, 2.0e-6 at 2 (``scripts/study_input_delay.py``,
which also runs the pipeline with the delays 0, 2, 4, 8); a delay between two samples fits both about equally and
flags neither."""


@dataclass
class DelayCheck:
    """Step 0: the configured input delay against one sample more and fewer (:func:`_delay_check`)."""

    configured: int
    better: int | None = None             # the neighbouring delay that fits significantly better, None: none does
    error_ratio: float = math.nan         # its output error over the configured delay's (the window after warm-up)
    ratios: dict[int, float] = field(default_factory=dict)   # every neighbour tried: delay -> error ratio

    def to_dict(self) -> dict[str, Any]:
        return {"configured": self.configured, "better": self.better, "error_ratio": _num(self.error_ratio),
                "ratios": {str(k): _num(v) for k, v in self.ratios.items()}}


@dataclass
class ExtraMode:
    """One K + 1 refit: the extra submodel found and how it moves the K modelled modes."""

    start_hz: float                       # the residual FRF's peak the extra mode was started at
    modal: np.ndarray                     # (3,) natural frequency [Hz], damping, gain of the extra mode
    gain_sigmas: float                    # |gain| / std(gain): the extra mode is real above N_SIGMA
    real: bool
    change: np.ndarray                    # (K, 3) relative change q_K+1 / q_K - 1 of the modelled modes
    change_sigmas: np.ndarray             # (K, 3) |q_K+1 - q_K| / std(q_K+1)
    relevant: np.ndarray                  # (K, 3) bool: moved beyond the relevance threshold and N_SIGMA
    modal_K: np.ndarray                   # (K, 3) the K-mode fit
    modal_K1: np.ndarray                  # (K, 3) the modelled modes in the K + 1 fit
    note: str = ""
    thetas: list[np.ndarray] | None = None   # the K + 1 fit's parameters (None: it failed)

    @property
    def moves(self) -> bool:
        return bool(self.real and np.any(self.relevant))

    def worst(self, thresholds: np.ndarray) -> tuple[int, int]:
        """(mode, quantity) of the largest relevant change relative to its threshold."""
        score = np.where(self.relevant, np.abs(self.change) / thresholds[None, :], -1.0)
        i, q = np.unravel_index(int(np.argmax(score)), score.shape)
        return int(i), int(q)

    def to_dict(self) -> dict[str, Any]:
        def nums(a: np.ndarray) -> list:
            return [[_num(v) for v in row] for row in np.atleast_2d(a)]
        return {"start_hz": self.start_hz, "natural_frequency_hz": _num(self.modal[0]),
                "damping_ratio": _num(self.modal[1]), "gain": _num(self.modal[2]),
                "gain_sigmas": _num(self.gain_sigmas),
                "real": self.real, "moves_modelled_modes": self.moves, "relative_change": nums(self.change),
                "change_sigmas": nums(self.change_sigmas), "relevant": np.asarray(self.relevant).tolist(),
                "note": self.note}


@dataclass
class OrderCheckResult:
    """Outcome of :func:`check_model_order`: ``state`` ``too_low`` or ``misfit`` (health WARN), ``adequate`` or
    ``skipped``."""

    state: str
    message: str
    n_bins: int = 0                       # valid leakage-free FRF bins compared
    n_misfit: int = 0                     # of them, significant misfits
    threshold: float = math.nan           # z above which a bin misfits
    extras: list[ExtraMode] = field(default_factory=list)
    window_s: tuple[float, float] = (math.nan, math.nan)
    seconds: float = math.nan
    frf: FRFEstimate | None = None

    misfit_hz: tuple[float, float] = (math.nan, math.nan)   # lowest and highest misfit bin
    n_misfit_estimate: int = 0            # misfit bins of the estimate checked (before its refit on the window)
    misfit_run_estimate: int = 0          # the estimate's longest run of misfit bins
    misfit_run: tuple[int, float, float] = (0, math.nan, math.nan)   # longest run of misfit bins: count, from, to Hz
    delay: DelayCheck | None = None       # step 0: the configured input delay against its neighbours
    explained_hz: list[float] = field(default_factory=list)  # candidates a real extra mode's refit explains (step 3)

    @property
    def flagged(self) -> bool:
        return self.state in MODEL_ORDER_FLAGGED

    @property
    def wrong_delay(self) -> bool:
        """Step 0 found a neighbouring input delay that fits significantly better than the configured one."""
        return self.delay is not None and self.delay.better is not None

    def to_dict(self) -> dict[str, Any]:
        return {"state": self.state, "message": self.message, "n_bins": self.n_bins, "n_misfit": self.n_misfit,
                "threshold": _num(self.threshold), "window_s": [_num(v) for v in self.window_s],
                "misfit_hz": [_num(v) for v in self.misfit_hz], "n_misfit_estimate": self.n_misfit_estimate,
                "misfit_run_estimate": self.misfit_run_estimate,
                "misfit_run": {"bins": self.misfit_run[0], "hz": [_num(v) for v in self.misfit_run[1:]]},
                "extra_modes": [e.to_dict() for e in self.extras],
                "significant_unmodelled_hz": [float(e.modal[0]) for e in self.extras if e.real],
                "candidates_explained_hz": [float(f) for f in self.explained_hz],
                "input_delay": None if self.delay is None else self.delay.to_dict()}


def _num(v: float) -> float | None:
    v = float(v)
    return v if math.isfinite(v) else None


def warmup_s(thetas: Sequence[np.ndarray], structures: Sequence[SubmodelStructure], rate_hz: float, n: int) -> float:
    """Filter warm-up of a window cut from a running loop (it always starts in motion): the offline warm-up of
    ``thetas`` (:func:`.offline.warmup_samples`: five decay times of the slowest mode, at most a quarter)."""
    from .offline import warmup_samples

    return warmup_samples(list(thetas), list(structures), rate_hz, n) / rate_hz


# the data of :func:`_fit`: u, y, rate_hz, r, controller, input_delay
FitData = tuple[np.ndarray, np.ndarray, float, np.ndarray | None, DiscreteController | None, int]


def _fit(u, y, rate_hz: float, r, controller, input_delay: int, structures, thetas, max_iterations: int,
         warmup: float):
    """Offline additive (CL)SRIVC ([A-SRIVC] eq. 29) from ``thetas``, the first ``warmup`` s only warming up the
    filters; ``None`` if it fails or is not finite. Raises :class:`.filters.ClosedLoopUnstableError` when the controller
    does not stabilize the start."""
    from ..estimation.filters import ClosedLoopUnstableError
    from .offline import identify

    try:
        res = identify(u, y, rate_hz, list(structures), [np.asarray(t, float) for t in thetas], r=r,
                       controller=controller, input_delay=input_delay, max_iterations=max_iterations,
                       warmup_s=warmup, tol=FIT_TOL)
    except ClosedLoopUnstableError:
        raise
    except (ValueError, np.linalg.LinAlgError):
        return None
    ok = all(np.all(np.isfinite(t)) for t in res.thetas) and all(
        t[0] > 0 and t[1] > 0 for t, s in zip(res.thetas, res.structures, strict=True) if s.n == 2)
    return res if ok and math.isfinite(res.cost) else None


def _delay_check(fit_K: Any, data: tuple, structures: list[SubmodelStructure], max_iterations: int,
                 warmup: float) -> DelayCheck:
    """Step 0: refit the K modes from ``fit_K`` with the input delay one sample shorter and longer and compare the
    models' simulated output errors (closed loop: from the reference through the controller; open loop: from the
    input) on the window after its warm-up. A neighbour better by :data:`DELAY_ERROR_RATIO`, paired over the window,
    is :attr:`DelayCheck.better` (the lower error when both are)."""
    from ..estimation.filters import ClosedLoopUnstableError

    u, y, rate_hz, r, controller, delay = data
    skip = min(int(round(warmup * rate_hz)), u.size // 2)
    out = DelayCheck(int(delay))

    def row(thetas: Sequence[np.ndarray], d: int) -> OrderRow:
        e_warm, e, resid = _held_out_error(thetas, structures, rate_hz, u, y, r, controller, d, skip)
        return OrderRow(len(structures), e_warm, e, residual=resid)

    try:
        base = row(fit_K.thetas, delay)
    except Exception:  # noqa: BLE001 - e.g. the controller does not stabilize the model: no comparison
        return out
    if not (np.isfinite(base.validation_error) and base.validation_error > 0.0):
        return out
    for d in (delay - 1, delay + 1):
        if d < 0:
            continue
        try:
            res = _fit(u, y, rate_hz, r, controller, d, structures, fit_K.thetas, max_iterations, warmup)
            cand = None if res is None else row(res.thetas, d)
        except (ClosedLoopUnstableError, ValueError, np.linalg.LinAlgError):
            cand = None
        if cand is None or not np.isfinite(cand.validation_error):
            continue
        ratio = cand.validation_error / base.validation_error
        out.ratios[d] = ratio
        if _significant_gain(cand, base, 1.0 - DELAY_ERROR_RATIO) and not ratio >= out.error_ratio \
                and not _start_explains(res.thetas, cand, data, structures, max_iterations, warmup, row):
            out.better, out.error_ratio = d, ratio
    return out


def _start_explains(thetas: Sequence[np.ndarray], cand: Any, data: tuple, structures: list[SubmodelStructure],
                    max_iterations: int, warmup: float, row: Any) -> bool:
    """Is the neighbour's gain the start's, not the delay's? The configured delay refitted from the neighbour's modes
    (``thetas``): when that fit is not significantly worse than the neighbour, the configured model had only stopped
    at a wrong optimum (guesses 5 and 5.5 Hz on a 5 + 40 Hz loop: the delay one sample shorter "fitted 500 times
    better" because its refit escaped the split mode, and the delay was blamed)."""
    from ..estimation.filters import ClosedLoopUnstableError

    u, y, rate_hz, r, controller, delay = data
    try:
        res = _fit(u, y, rate_hz, r, controller, delay, structures, thetas, max_iterations, warmup)
        again = None if res is None else row(res.thetas, delay)
    except (ClosedLoopUnstableError, ValueError, np.linalg.LinAlgError):
        return False
    if again is None or not np.isfinite(again.validation_error):
        return False
    return not _significant_gain(cand, again, 1.0 - DELAY_ERROR_RATIO)


def _candidates(frf: FRFEstimate, G_model: np.ndarray, z: np.ndarray, usable: np.ndarray, threshold: float,
                modal_K: np.ndarray, structures: Sequence[SubmodelStructure], input_delay: int) -> list[Any]:
    """Resonances of the residual FRF that misfit significantly and are no modelled mode (step 2), largest first."""

    res_frf = replace(frf, G=frf.G - G_model)
    out = []
    for c in find_candidates(res_frf, input_delay):
        f = c.natural_frequency_hz
        if c.integrators or f <= 0.0:
            continue
        own = [abs(f - m[0]) <= max(2.0 * frf.resolution_hz, 2.0 * m[1] * m[0])
               for m, s in zip(modal_K, structures, strict=True) if s.is_mode and np.isfinite(m[0])]
        if any(own):
            continue
        peak = _local_misfit(frf, z, usable, f)
        if peak > threshold:
            out.append((peak, c))
    out.sort(key=lambda pc: -pc[0])
    near_bins = 2.5 * frf.resolution_hz
    seen: list[float] = []
    picked = []
    for _, c in out:
        if all(abs(c.natural_frequency_hz - f) > near_bins for f in seen):
            picked.append(c)
            seen.append(c.natural_frequency_hz)
    return picked[:MAX_CANDIDATES]


def _local_misfit(frf: FRFEstimate, z: np.ndarray, usable: np.ndarray, f_hz: float) -> float:
    """The largest normalized misfit ``z`` of the compared bins within 2.5 resolutions of ``f_hz`` (0: none)."""
    local = usable & (np.abs(frf.freqs_hz - f_hz) <= 2.5 * frf.resolution_hz)
    return float(np.max(z[local])) if local.any() else 0.0


def _explained(frf: FRFEstimate, usable: np.ndarray, threshold: float, f_hz: float,
               explaining: Sequence[np.ndarray]) -> bool:
    """Does one of the real extra modes' K + 1 models (their misfits ``z`` in ``explaining``) fit the data near
    ``f_hz``, no bin within 2.5 resolutions above ``threshold``? Then a candidate there is no further resonance
    (step 3)."""
    return any(_local_misfit(frf, z1, usable, f_hz) <= threshold for z1 in explaining)


def _extra_mode(cand: Any, fit_K: Any, data: FitData, structures: list[SubmodelStructure], band: tuple[float, float],
                thresholds: np.ndarray, max_iterations: int, warmup: float) -> ExtraMode:
    """Refit with the candidate as submodel K + 1 (step 3) and measure how it moves the modelled modes (step 4)."""
    from ..estimation.filters import ClosedLoopUnstableError

    K = len(structures)
    nan3 = np.full((K, 3), np.nan)
    res, gain, note = None, cand.gain, ""
    n = data[0].size
    warmup = max(warmup, warmup_s([cand.theta()], [cand.structure], data[2], n))
    for _ in range(4):   # a start the controller does not stabilize: a smaller extra gain (it is a residual)
        try:
            res = _fit(*data, [*structures, cand.structure], [*fit_K.thetas, theta_from_modal(
                cand.natural_frequency_hz, cand.damping_ratio, gain)], max_iterations, warmup)
            break
        except ClosedLoopUnstableError:
            gain *= 0.25
    if res is None:
        return ExtraMode(cand.natural_frequency_hz, np.full(3, np.nan), 0.0, False, nan3, nan3,
                         np.zeros((K, 3), bool), fit_K.modal, nan3, "K + 1 fit failed")
    modal = np.asarray(res.modal, float)
    std = np.asarray(res.modal_std, float)
    extra, extra_std = modal[K], std[K]
    gain_sigmas = abs(extra[2]) / extra_std[2] if extra_std[2] > 0 else math.inf
    in_band = band[0] <= extra[0] <= band[1]
    lower_cost = res.cost < fit_K.cost
    real = bool(gain_sigmas > N_SIGMA and in_band and lower_cost)
    if not real:
        note = ", ".join(w for w, bad in (("gain within noise", gain_sigmas <= N_SIGMA),
                                          ("outside the valid band", not in_band),
                                          ("no lower output error", not lower_cost)) if bad)
    mK, mK1 = np.asarray(fit_K.modal, float)[:K], modal[:K]
    with np.errstate(divide="ignore", invalid="ignore"):
        change = mK1 / mK - 1.0
        sigmas = np.abs(mK1 - mK) / std[:K]
    change = np.where(np.isfinite(change), change, 0.0)
    sigmas = np.where(np.isfinite(sigmas), sigmas, 0.0)
    relevant = (np.abs(change) > thresholds[None, :]) & (sigmas > N_SIGMA)
    for i, s in enumerate(structures):
        if not s.is_mode:   # rigid body: frequency and damping are not quantities of it
            relevant[i, :2] = False
    return ExtraMode(cand.natural_frequency_hz, extra, float(gain_sigmas), real, change, sigmas, relevant, mK, mK1,
                     note, [np.asarray(t, float) for t in res.thetas])


def _start_thetas(modal: np.ndarray, structures: Sequence[SubmodelStructure],
                  fallback: Sequence[np.ndarray]) -> list[np.ndarray]:
    """Parameter vectors from the estimate's ``(f, zeta, gain)`` rows (the fallback where they do not apply)."""
    out = []
    for row, s, fb in zip(np.asarray(modal, float), structures, fallback, strict=True):
        if s.is_mode and np.all(np.isfinite(row[:3])) and row[0] > 0:
            out.append(theta_from_modal(*row[:3]))
        elif s.n == 0 and np.isfinite(row[2]):
            out.append(np.array([row[2]]))
        else:
            out.append(np.asarray(fb, float))
    return out


def check_model_order(thetas: Sequence[np.ndarray], structures: Sequence[SubmodelStructure], u, y, rate_hz: float,
                      *, r=None, controller: DiscreteController | None = None, input_delay: int = 0,
                      min_change: Sequence[float] = (0.02, 0.20, 0.10), relevance: float = 0.25,
                      max_iterations: int = 30) -> OrderCheckResult:
    """Does an unmodelled resonance in the data move the modelled modes? See the module docstring (steps 1-4).

    ``thetas``: the current model (start of the K-mode refit); ``u, y`` (and ``r`` with ``controller`` in closed
    loop): the window, of which the longest finite stretch is used. ``min_change``: ``faults.min_change.*``
    (natural frequency, damping, gain); a modelled quantity moved by more than ``relevance`` times it is relevant.
    Never raises on data problems: the result is ``skipped`` with the reason."""
    c0 = time.perf_counter()
    structures = list(structures)
    closed = controller is not None and r is not None
    r = np.asarray(r, float) if closed else None
    u, y = np.asarray(u, float), np.asarray(y, float)
    seg = longest_finite(r, u, y)
    n = seg.stop - seg.start
    if n < MIN_WINDOW_S * rate_hz:
        return OrderCheckResult("skipped", f"only {n / rate_hz:.2f} s of contiguous valid samples "
                                f"(need {MIN_WINDOW_S:g} s)", seconds=time.perf_counter() - c0)
    data: FitData = (u[seg], y[seg], rate_hz, None if r is None else r[seg], controller if closed else None,
                     input_delay)
    thresholds = relevance * np.asarray(min_change, float)
    from ..estimation.filters import ClosedLoopUnstableError

    warmup = warmup_s(thetas, structures, rate_hz, n)
    try:
        fit_K = _fit(*data, structures, thetas, max_iterations, warmup)
    except ClosedLoopUnstableError:
        fit_K = None
    if fit_K is None:
        return OrderCheckResult("skipped", "the K-mode refit on the window failed", seconds=time.perf_counter() - c0)
    delay = _delay_check(fit_K, data, structures, max_iterations, warmup)
    try:
        frf = estimate_frf(data[0], data[1], rate_hz, data[3])
    except ValueError as exc:
        return OrderCheckResult("skipped", one_line(exc), seconds=time.perf_counter() - c0)
    G_model = model_frf_on_bins(frf, fit_K.thetas, structures, input_delay)
    z, usable, thr = misfit(frf, G_model)
    n_mis = int(np.sum(z > thr))
    out = OrderCheckResult("adequate", "", int(usable.sum()), n_mis, thr, frf=frf, delay=delay)
    if n_mis:
        f_mis = frf.freqs_hz[z > thr]
        out.misfit_hz = (float(f_mis.min()), float(f_mis.max()))
        out.misfit_run = longest_misfit_run(frf, z, usable, thr)
    z_est, _, _ = misfit(frf, model_frf_on_bins(frf, [np.asarray(t, float) for t in thetas], structures, input_delay))
    out.n_misfit_estimate = int(np.sum(z_est > thr))
    out.misfit_run_estimate = longest_misfit_run(frf, z_est, usable, thr)[0]
    band = frf.band_hz
    if n_mis and band is not None and delay.better is None:   # a wrong delay's misfit is no unmodelled mode
        modal_K = np.asarray(fit_K.modal, float)
        explaining: list[np.ndarray] = []   # the misfit z of each real extra mode's K + 1 model
        for cand in _candidates(frf, G_model, z, usable, thr, modal_K, structures, input_delay):
            if _explained(frf, usable, thr, cand.natural_frequency_hz, explaining):
                out.explained_hz.append(cand.natural_frequency_hz)   # the skirt of a resonance found: no refit
                continue
            extra = _extra_mode(cand, fit_K, data, structures, band, thresholds, max_iterations, warmup)
            if extra.real and any(abs(extra.modal[0] - e.modal[0]) <= frf.resolution_hz for e in out.extras if e.real):
                continue                      # the refit converged onto a resonance already found
            out.extras.append(extra)
            if extra.moves:
                break
            if extra.real and extra.thetas is not None:   # real: the K + 1 fit succeeded
                explaining.append(misfit(frf, model_frf_on_bins(frf, extra.thetas, [*structures, cand.structure],
                                                                input_delay))[0])
    out.seconds = time.perf_counter() - c0
    out.state, out.message = _verdict(out, thresholds)
    return out


def check_start(found: Any, r, u, y, rate_hz: float, *, controller: DiscreteController | None = None,
                input_delay: int = 0, min_change: Sequence[float] = (0.02, 0.20, 0.10), relevance: float = 0.25,
                max_iterations: int = 30) -> OrderCheckResult | None:
    """The automatic start's model (``found``: :class:`.modefind.ModeFindResult`) against the FRF of the window it was
    found on: None when at most :data:`START_SCREEN_FRACTION` of the valid bins misfit, fewer than
    :data:`MISFIT_RUN_BINS` of them in a row (a few milliseconds: that FRF is already estimated); otherwise the whole
    check (:func:`check_model_order`), which tells a wrong start (``misfit``,
    ``too_low``) from modes left out that do not matter. So a start that misfits its own data is flagged from the
    first estimate, not after the regular check's window (4 memory lengths later)."""
    return check_initial_model(found.thetas, found.structures, r, u, y, rate_hz, frf=found.frf,
                               controller=controller, input_delay=input_delay, min_change=min_change,
                               relevance=relevance, max_iterations=max_iterations)


def check_initial_model(thetas: Sequence[np.ndarray], structures: Sequence[SubmodelStructure], r, u, y,
                        rate_hz: float, *, frf: FRFEstimate | None = None,
                        controller: DiscreteController | None = None, input_delay: int = 0,
                        min_change: Sequence[float] = (0.02, 0.20, 0.10), relevance: float = 0.25,
                        max_iterations: int = 30) -> OrderCheckResult | None:
    """The screen of a start on its own window ``r, u, y`` (invalid outputs NaN): :func:`fits_its_frf` against
    ``frf`` (the automatic start's, :func:`check_start`) or, for a model initialized from guesses (or again after a
    divergence), the FRF of the window's longest finite stretch. None when the model fits (or the stretch is too
    short for an FRF), otherwise the whole check (:func:`check_model_order`, on that stretch)."""
    if frf is None:
        closed = controller is not None and r is not None
        seg = longest_finite(np.asarray(r, float) if closed else None, np.asarray(u, float), np.asarray(y, float))
        if seg.stop - seg.start < MIN_WINDOW_S * rate_hz:
            return None
        try:
            frf = estimate_frf(u[seg], y[seg], rate_hz, r[seg] if closed else None)
        except ValueError:
            return None
    if fits_its_frf(frf, model_frf_on_bins(frf, thetas, structures, input_delay)):
        return None
    return check_model_order(thetas, structures, u, y, rate_hz, r=r, controller=controller,
                             input_delay=input_delay, min_change=min_change, relevance=relevance,
                             max_iterations=max_iterations)


def _verdict(res: OrderCheckResult, thresholds: np.ndarray) -> tuple[str, str]:
    """State and the one health line."""
    d = res.delay
    if d is not None and d.better is not None:   # res.wrong_delay
        return "misfit", (f"the configured input delay misfits the data: with input_delay_samples {d.better} instead "
                          f"of {d.configured} the model's output error on this window is {100 * d.error_ratio:.2g} % "
                          "of it; check input_delay_samples (the loop's delay is part of the model): not a fault of "
                          "the plant")
    moving = [e for e in res.extras if e.moves]
    if moving:
        e = max(moving, key=lambda x: float(np.max(np.where(x.relevant, np.abs(x.change) / thresholds, 0.0))))
        i, q = e.worst(thresholds)
        others = [f"{QUANTITY_NAMES[k]} {100 * e.change[i, k]:+.2g} %" for k in range(3) if k != q and e.relevant[i, k]]
        also = f"; also {', '.join(others)}" if others else ""
        return "too_low", (f"model order too low: an unmodelled resonance near {e.modal[0]:.4g} Hz moves mode {i + 1} "
                           f"{QUANTITY_NAMES[q]} by {100 * e.change[i, q]:+.2g} % ({e.modal_K[i, q]:.5g} without it, "
                           f"{e.modal_K1[i, q]:.5g} with it{also}); add a mode near {e.modal[0]:.4g} Hz")
    real = [f"{e.modal[0]:.4g} Hz" for e in res.extras if e.real]
    gross = max(MIN_MISFIT_BINS, MISFIT_FRACTION * res.n_bins)
    if res.n_misfit_estimate >= gross and res.n_misfit < gross:
        return "misfit", (f"the estimate misfits the data: {res.n_misfit_estimate} of {res.n_bins} FRF bins differ "
                          f"beyond their uncertainty, while the same modes refitted "
                          "on this window fit it: the estimate is a wrong optimum or has not converged; not a fault "
                          "of the plant")
    # "fits": as clean as the start screen asks (a correct model misfits a bin or two; 5-15 % is a wrong start's)
    estimate_fits = (res.n_misfit_estimate < max(MIN_MISFIT_BINS, START_SCREEN_FRACTION * res.n_bins)
                     and res.misfit_run_estimate < MISFIT_RUN_BINS)
    refit_misfits = res.n_misfit >= gross or res.misfit_run[0] >= MISFIT_RUN_BINS
    if not real and refit_misfits and estimate_fits:
        return "adequate", (f"the estimate fits the FRF within its uncertainty ({res.n_misfit_estimate} of "
                            f"{res.n_bins} bins misfit, at most {res.misfit_run_estimate} in a row); its refit on "
                            f"this window misfits {res.n_misfit} (the refit's failure, not the model's)")
    if not real and res.n_misfit >= gross:
        lo, hi = res.misfit_hz
        return "misfit", (f"model misfits the data: {res.n_misfit} of {res.n_bins} FRF bins ({lo:.4g}-{hi:.4g} Hz) "
                          "differ beyond their uncertainty and no unmodelled resonance explains it; the modes may be "
                          "a wrong optimum or too few: not a fault of the plant")
    run, lo, hi = res.misfit_run
    if not real and run >= MISFIT_RUN_BINS:
        return "misfit", (f"model misfits the data: {run} FRF bins in a row ({lo:.4g}-{hi:.4g} Hz; {res.n_misfit} of "
                          f"{res.n_bins} in all) differ beyond their uncertainty and no unmodelled resonance explains "
                          "it; modes may be missing or merged there: not a fault of the plant")
    if real:
        return "adequate", (f"unmodelled resonance(s) at {', '.join(real)} do not move the modelled modes beyond "
                            f"{', '.join(f'{100 * t:.2g} %' for t in thresholds)} ({', '.join(QUANTITIES)})")
    if res.n_misfit:
        return "adequate", f"{res.n_misfit} of {res.n_bins} FRF bins misfit, no unmodelled resonance found there"
    return "adequate", f"the model fits the FRF within its uncertainty ({res.n_bins} bins)"


@dataclass
class ModelOrderCheck:
    """The pipeline's model-order check: collect a window of contiguous data after the initialization, check once
    per run, report on health.

    The window is ``memory_lengths`` x the longest memory (0: off). Samples must come on the grid: a block that does
    not follow the previous one (a data gap, a stuck-sensor episode, a re-initialization in between) starts the
    window again."""

    rate_hz: float
    memory_lengths: float
    relevance: float
    blocks: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = field(default_factory=list)
    n: int = 0
    t_start_s: float = math.nan
    t_next_s: float = math.nan            # time the next contiguous sample would have
    window_s: float = math.nan
    result: OrderCheckResult | None = None
    start_result: OrderCheckResult | None = None   # a flagged check of the automatic start on its own window

    @property
    def enabled(self) -> bool:
        return self.memory_lengths > 0.0

    @property
    def pending(self) -> bool:
        return self.enabled and self.result is None

    @property
    def flagged(self) -> bool:
        """The model is flagged now: by the check, or (until it runs) by the automatic start's check on its own
        window."""
        if self.result is not None:
            return self.result.flagged
        return self.start_result is not None and self.start_result.flagged

    def clear(self) -> None:
        self.blocks, self.n, self.t_start_s = [], 0, math.nan

    def add(self, r: np.ndarray, u: np.ndarray, y: np.ndarray, valid: np.ndarray, t_end_rel: float,
            longest_memory_s: float) -> bool:
        """Buffer a block of grid samples ending at ``t_end_rel`` (invalid ones as NaN outputs); True when the window
        is full."""
        if not self.pending or u.size == 0:
            return False
        h = 1.0 / self.rate_hz
        t_first = t_end_rel - (u.size - 1) * h
        if self.n and abs(t_first - self.t_next_s) > 0.5 * h:
            self.clear()
        self.t_next_s = t_end_rel + h
        self.window_s = max(self.memory_lengths * float(longest_memory_s), MIN_WINDOW_S)
        need = max(int(round(self.window_s * self.rate_hz)), 1)
        take = min(u.size, need - self.n)
        if self.n == 0:
            self.t_start_s = t_first
        self.blocks.append((r[:take].copy(), u[:take].copy(), np.where(valid[:take], y[:take], np.nan)))
        self.n += take
        return self.n >= need

    def window(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The collected window ``(r, u, y)`` (invalid outputs NaN)."""
        r, u, y = (np.concatenate([b[k] for b in self.blocks]) for k in range(3))
        return r, u, y

    def run(self, modal: np.ndarray, cfg: Any, min_change: Sequence[float]) -> str | None:
        """Check the full window against the current estimate ``modal`` (K, >= 3); returns the notice line when the
        model is flagged (otherwise the finding is only in ``health['model_order']``)."""
        r, u, y = self.window()
        t0 = self.t_start_s
        self.clear()
        structures = list(cfg.structures)
        thetas = _start_thetas(modal, structures, [m.theta0() for m in cfg.modes])
        try:
            res = check_model_order(thetas, structures, u, y, self.rate_hz, r=r if cfg.closed_loop else None,
                                    controller=cfg.controller if cfg.closed_loop else None,
                                    input_delay=cfg.input_delay_samples, min_change=min_change,
                                    relevance=self.relevance, max_iterations=cfg.estimator.init_max_iterations)
        except Exception as exc:  # noqa: BLE001 - a failed check is a line on health, never a crash
            res = OrderCheckResult("skipped", f"{type(exc).__name__}: {one_line(exc)}")
        res.window_s = (t0, t0 + u.size / self.rate_hz)
        res.frf = None                        # not kept in the pipeline's memory
        self.result = res
        if not res.flagged:
            return None
        return f"model-order check on t={res.window_s[0]:.1f}–{res.window_s[1]:.1f} s: {res.message}"

    def apply(self, health: dict[str, Any], warn_level: int) -> None:
        """``health['model_order']`` and, when the order is too low, the reason line and at least WARN (no hold)."""
        if not self.enabled:
            health["model_order"] = {"state": "off"}
            return
        if self.result is None:
            start = self.start_result
            if start is not None and start.flagged:   # the start misfits its own window: flagged until checked again
                health["model_order"] = {**start.to_dict(), "stage": "start", "collected_s": self.n / self.rate_hz}
                health["reasons"] = [*health["reasons"], start.message]
                health["level"] = max(int(health["level"]), int(warn_level))
                health["ok"] = False
                return
            health["model_order"] = {"state": "pending", "collected_s": self.n / self.rate_hz,
                                     "window_s": _num(self.window_s)}
            return
        health["model_order"] = self.result.to_dict()
        if self.result.flagged:
            health["reasons"] = [*health["reasons"], self.result.message]
            health["level"] = max(int(health["level"]), int(warn_level))
            health["ok"] = False
