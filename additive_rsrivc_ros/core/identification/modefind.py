"""Modes and model order from the data: FRF peaks refined by the offline additive (CL)SRIVC.

1. :func:`find_candidates`: on the valid part of the nonparametric FRF (:mod:`.frf`, delay and half-sample hold removed
from the phase), resonance peaks of the 5-bin mean of ``log10 |G|`` (prominence above ``MIN_PROMINENCE_DECADES`` and 3
noise stds): frequency by a parabola, damping by the half-power width ``zeta = (f2 - f1) / (2 f_peak)`` (never below the
resolution), gain from ``G(j omega_n) = -j b0 / (2 zeta)``; a rigid body ``b0/p^l`` from a ``-20 l`` dB/decade low band
where ``G (j omega)^l`` is real; :func:`finer_candidates` the same on finer FRFs.

2. :func:`find_modes`: for K = 1, 2, ... a start (the best smaller model plus a peak, its residual FRF's strongest
resonance, or a rigid body; each also refined on the FRF, :func:`refine_on_frf`) is fitted by the offline additive
CLSRIVC ([A-SRIVC] eq. 20/29; open loop SRIVC) on the first part of the record and judged by its output error on the
rest (closed loop ``T_o r``, open loop ``G u``). A larger K wins only if that error drops by more than ``margin`` (2 %)
and the gain holds throughout the held-out data (:func:`_significant_gain`), and only if the gain comes from the added
mode (:func:`_check_relevance`); the chosen model is refitted on the whole record.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field, replace
from typing import Any, TypeVar

import numpy as np

from ..estimation.estimator import MonitorSettings
from ..model import TWO_PI, SubmodelStructure, guess_structure, guess_theta, modal_from_theta
from .frf import FRFEstimate, estimate_frf, longest_finite, model_frf_on_bins
from .frf_misfit import fits_its_frf
from .offline.stable import fit_usable

MIN_PROMINENCE_DECADES = 0.1  # 2 dB
DEFAULT_MARGIN = 0.02
HELD_OUT_BATCHES = 10  # batches of the held-out data for the paired test of an order's gain (_significant_gain)
GAIN_T = 2.821  # one-sided 1 % quantile of Student's t with HELD_OUT_BATCHES - 1 degrees of freedom
RIGID_SLOPE_TOLERANCE = 0.25
RIGID_REALNESS = 0.3  # median |Im| / |.| of G (j omega)^l over the slope bins of a rigid body b0/p^l (phase < 17 deg)
SMOOTH_BINS = 5
ALTERNATIVES = 3  # new peaks tried for each larger order
STOP_AFTER_MISSES = 2  # order scan stops after this many consecutive orders without a significant gain
SCAN_TOL = 1e-4  # relative parameter change that ends an order-scan fit (the chosen order is refitted to 1e-7)
SCAN_MAX_ITERATIONS = 20  # an order-scan fit still moving after this many iterations is judged where it stands
SCAN_SETTLE = 1e-3  # ... and, after an order that fits its FRF, one no better than it whose output error no longer
# falls by this fraction (offline.additive_iv; _evaluate)
FINAL_TOL = 1e-7  # identify()'s default: the refit of the chosen order on the whole record
FINER_FACTORS = (2, 4)  # low-band candidates also from FRFs with 2x and 4x longer segments (finer resolution)
FRF_REFINE = True  # the order scan also tries each start refined on the FRF (refine_on_frf), before the start
QUICK_FRF_FTOL = 1e-4  # refine_on_frf of the starts of an order after one that fits its FRF: stop when a step lowers
# the weighted misfit by less than this fraction (the added mode has nothing to fit; it wandered for hundreds of
# evaluations at a flat misfit)
DEGENERATE_BAND_BINS = 0.02  # a start refined on the FRF to a mode narrower than this many bins is dropped
FINER_BAND_BINS = 20  # ... below this many bins of the default resolution, where a peak has too few bins

SettingsT = TypeVar("SettingsT", bound=MonitorSettings)   # autostart_config returns the type it is given


@dataclass(frozen=True)
class Candidate:
    """One candidate submodel read off the FRF."""

    natural_frequency_hz: float
    damping_ratio: float
    gain: float
    prominence_decades: float = 0.0
    integrators: int = 0

    @property
    def structure(self) -> SubmodelStructure:
        return guess_structure(self.natural_frequency_hz, self.integrators)

    def theta(self) -> np.ndarray:
        return guess_theta(self.natural_frequency_hz, self.damping_ratio, self.gain)

    def to_dict(self) -> dict[str, Any]:
        return {"natural_frequency_hz": self.natural_frequency_hz, "damping_ratio": self.damping_ratio,
                "gain": self.gain, "integrators": self.integrators, "prominence_db": 20 * self.prominence_decades}


@dataclass
class OrderRow:
    """One line of the order-selection table."""

    K: int
    fit_error: float
    validation_error: float
    accepted: bool = False
    converged: bool = False
    message: str = ""
    redundant: bool = False  # a mode of this fit adds less than the margin: its reduction is a K - 1 model
    residual: np.ndarray | None = field(default=None, repr=False, compare=False)  # held-out output error
    modes: list[Candidate] = field(default_factory=list)  # the submodels of this order's kept fit (none: no fit)

    def to_dict(self) -> dict[str, Any]:
        def num(v: float) -> float | None:
            return float(v) if np.isfinite(v) else None
        return {"K": self.K, "fit_error": num(self.fit_error), "validation_error": num(self.validation_error),
                "accepted": self.accepted, "converged": self.converged, "message": self.message,
                "redundant": self.redundant,
                "modes": [{"natural_frequency_hz": num(c.natural_frequency_hz), "damping_ratio": num(c.damping_ratio),
                           "gain": num(c.gain), "integrators": c.integrators} for c in self.modes]}


@dataclass
class ModeFindResult:
    """Chosen order, modes and the evidence (order-selection table, FRF summary, candidates)."""

    K: int
    structures: list[SubmodelStructure]
    thetas: list[np.ndarray]
    modal: np.ndarray  # (K, 3): f_hz, zeta, gain
    identifiable: list[bool]
    table: list[OrderRow]
    frf: FRFEstimate
    candidates: list[Candidate]
    identification: Any = None
    message: str = ""
    peaks_hz: list[float] = field(default_factory=list)

    def frf_summary(self) -> dict[str, Any]:
        out = self.frf.summary()
        out["peaks_hz"] = [c.natural_frequency_hz for c in self.candidates if c.natural_frequency_hz > 0]
        out["rigid_body"] = next((c.integrators for c in self.candidates if c.natural_frequency_hz == 0), 0)
        return out

    def to_dict(self) -> dict[str, Any]:
        return {"K": self.K, "message": self.message,
                "modes": [{"natural_frequency_hz": float(m[0]), "damping_ratio": float(m[1]), "gain": float(m[2]),
                           "integrators": s.integrators, "identifiable": ok}
                          for m, s, ok in zip(self.modal, self.structures, self.identifiable, strict=True)],
                "order_selection": [row.to_dict() for row in self.table], "frf": self.frf_summary(),
                "candidates": [c.to_dict() for c in self.candidates]}


def _compensated(frf: FRFEstimate, input_delay: int) -> np.ndarray:
    """``G`` with the input delay and the hold's half sample removed from the phase."""
    w = TWO_PI * frf.freqs_hz
    return frf.G * np.exp(1j * w * (input_delay + 0.5) / frf.rate_hz)


def _rigid_body(f: np.ndarray, g: np.ndarray, first_peak_hz: float) -> Candidate | None:
    """``b0/p^l`` when the lowest valid decade (below a third of the first peak) falls with slope ``-l``."""
    sel = (f <= min(f[0] * 10.0, first_peak_hz / 3.0))
    if sel.sum() < 5:
        return None
    slope = np.polyfit(np.log10(f[sel]), np.log10(np.abs(g[sel])), 1)[0]
    for ell in (2, 1):
        if abs(slope + ell) < RIGID_SLOPE_TOLERANCE:
            c = g[sel] * (1j * TWO_PI * f[sel]) ** ell   # b0 for b0/p^l (minus the modes' static gains x w^l): real
            b0 = float(np.median(np.real(c)))
            # a damped resonance's roll-off can average the same slope, but its c turns by 90 degrees
            if b0 != 0.0 and float(np.median(np.abs(np.imag(c)) / np.maximum(np.abs(c), 1e-300))) < RIGID_REALNESS:
                return Candidate(0.0, 0.0, b0, 0.0, ell)
    return None


def _half_power_damping(f: np.ndarray, mag: np.ndarray, k: int, fp: float, resolution_hz: float) -> float:
    """``(f2 - f1)/(2 fp)`` from the half-power points around index ``k`` of a contiguous valid run."""
    level = mag[k] / np.sqrt(2.0)
    edges = []
    for step in (-1, 1):
        j = k
        while 0 <= j + step < f.size and mag[j + step] > level and abs(f[j + step] - f[j]) <= 1.5 * resolution_hz:
            j += step
        nxt = j + step
        if 0 <= nxt < f.size and abs(f[nxt] - f[j]) <= 1.5 * resolution_hz:
            x = (level - mag[j]) / (mag[nxt] - mag[j])  # linear interpolation to the half-power level
            edges.append(abs(f[j] + x * (f[nxt] - f[j]) - fp))
    if not edges:
        width = 2.0 * resolution_hz
    else:
        width = 2.0 * max(edges) if len(edges) == 1 else sum(edges)
    return float(max(width, resolution_hz) / (2.0 * fp))


def _smoothed(logm: np.ndarray, f: np.ndarray, resolution_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """Mean of ``log10 |G|`` over ``SMOOTH_BINS`` neighbouring valid bins (the Hann window's main lobe), so that a
    noise spike or the leakage step next to a reference line is not a peak; a real peak, already as wide as the
    main lobe, keeps its place. Also returns how many valid bins each mean used."""
    half = SMOOTH_BINS // 2
    out = logm.copy()
    count = np.ones(logm.size, dtype=int)
    for k in range(logm.size):
        near = slice(max(0, k - half), min(logm.size, k + half + 1))
        sel = np.abs(f[near] - f[k]) <= (half + 0.5) * resolution_hz
        out[k] = float(np.mean(logm[near][sel]))
        count[k] = int(sel.sum())
    return out, count


def peak_prominences(x: np.ndarray, min_prominence: float) -> tuple[np.ndarray, np.ndarray]:
    """Local maxima of ``x`` (a plateau counts once, at its middle sample) whose topographic prominence is at least
    ``min_prominence``: ``x[peak]`` minus the higher of the two lowest points between the peak and the nearest
    higher sample on each side (or the end). The definition of ``scipy.signal.find_peaks(x, prominence=...)``,
    without its 1 s import (scipy.signal and scipy.stats) on the diagnosis path. Returns ``(indices, prominences)``.
    """
    x = np.asarray(x, dtype=float)
    peaks = []
    i, n = 1, x.size
    while i < n - 1:
        if x[i - 1] < x[i]:
            j = i
            while j + 1 < n - 1 and x[j + 1] == x[i]:
                j += 1
            if x[j + 1] < x[i]:
                peaks.append((i + j) // 2)
                i = j
        i += 1
    idx, prom = [], []
    for k in peaks:
        left = x[:k][::-1]
        higher = np.flatnonzero(left > x[k])
        left_min = float(np.min(left[:higher[0]] if higher.size else left)) if left.size else x[k]
        right = x[k + 1:]
        higher = np.flatnonzero(right > x[k])
        right_min = float(np.min(right[:higher[0]] if higher.size else right)) if right.size else x[k]
        p = x[k] - max(left_min, right_min)
        if p >= min_prominence:
            idx.append(k)
            prom.append(p)
    return np.asarray(idx, dtype=int), np.asarray(prom, dtype=float)


def find_candidates(frf: FRFEstimate, input_delay: int = 0,
                    frequency_range_hz: tuple[float, float] | None = None,
                    first_peak_hz: float = np.inf) -> list[Candidate]:
    """Candidate submodels from the valid FRF: rigid body first (if any), then peaks by decreasing prominence. The
    rigid-body slope is sought below a third of the lowest peak found here or ``first_peak_hz``, whichever is lower
    (a resonance's roll-off above it also falls at -40 dB/decade)."""
    sel = frf.valid.copy()
    if frequency_range_hz is not None:
        sel &= (frf.freqs_hz >= frequency_range_hz[0]) & (frf.freqs_hz <= frequency_range_hz[1])
    if sel.sum() < 3:
        return []
    f = frf.freqs_hz[sel]
    g = _compensated(frf, input_delay)[sel]
    mag = np.abs(g)
    logm = np.log10(np.maximum(mag, np.finfo(float).tiny))
    rel_std = frf.std[sel] / np.maximum(mag, np.finfo(float).tiny)  # noise only: leakage steps are signal
    smooth, count = _smoothed(logm, f, frf.resolution_hz)
    idx, proms = peak_prominences(smooth, MIN_PROMINENCE_DECADES)
    peaks = []
    for k, prom in zip(idx, proms, strict=True):
        # a resonance in an informed region has valid neighbours; an isolated valid bin in a noisy region is
        # a chance coherence, not a peak
        if count[k] < 3 or prom < 3.0 * rel_std[k] / np.log(10.0) / np.sqrt(count[k]):
            continue
        near = np.flatnonzero(np.abs(f - f[k]) <= 2.5 * frf.resolution_hz)
        k = int(near[np.argmax(logm[near])])  # the raw maximum next to the smoothed peak
        fp = f[k]
        if 0 < k < f.size - 1 and f[k + 1] - f[k - 1] < 2.5 * frf.resolution_hz:
            den = logm[k - 1] - 2.0 * logm[k] + logm[k + 1]
            if den < 0:
                fp = f[k] + 0.5 * (logm[k - 1] - logm[k + 1]) / den * frf.resolution_hz
        zeta = min(_half_power_damping(f, mag, k, fp, frf.resolution_hz), 0.7)
        b0 = -2.0 * zeta * float(np.imag(g[k]))
        if abs(b0) < 0.2 * 2.0 * zeta * mag[k]:  # phase not near -90 degrees: keep the magnitude, sign of Im
            b0 = 2.0 * zeta * mag[k] * (1.0 if np.imag(g[k]) <= 0 else -1.0)
        peaks.append(Candidate(float(fp), zeta, b0, float(prom)))
    peaks.sort(key=lambda c: -c.prominence_decades)
    rigid = _rigid_body(f, g, min(min((c.natural_frequency_hz for c in peaks), default=f[-1]), first_peak_hz))
    return ([rigid] if rigid is not None else []) + peaks


def finer_candidates(u, y, rate_hz: float, r, frf: FRFEstimate, input_delay: int,
                     frequency_range_hz: tuple[float, float] | None,
                     candidates: list[Candidate]) -> list[Candidate]:
    """``candidates`` plus the low-frequency peaks that only a finer resolution shows. Welch averaging with enough
    averages gives ``frf.resolution_hz`` (0.5 Hz for 20 s): a mode at 1-3 Hz then spans 2-6 bins, the 5-bin mean
    flattens it and a square wave's lines, one every few bins, make a staircase of it. Below ``FINER_BAND_BINS``
    default bins the same test (valid bins, prominence, noise) runs on FRFs with ``FINER_FACTORS`` times longer
    segments (fewer averages: the coherence and variance bounds grow accordingly); a peak not within 15 % of a
    known candidate is appended, after them (the order scan tries them last), and a rigid-body slope, if the
    default FRF showed none, comes first (it always counts as one submodel)."""
    out = list(candidates)
    top = FINER_BAND_BINS * frf.resolution_hz
    lo, hi = frequency_range_hz if frequency_range_hz is not None else (0.0, np.inf)
    for factor in FINER_FACTORS:
        nperseg = factor * frf.nperseg
        if u.size < 2 * nperseg or lo >= min(hi, top):
            break
        try:
            fine = estimate_frf(u, y, rate_hz, r, nperseg=nperseg)
        except ValueError:
            break
        known = min((k.natural_frequency_hz for k in out if k.natural_frequency_hz > 0.0), default=np.inf)
        for c in find_candidates(fine, input_delay, (lo, min(hi, top)), first_peak_hz=known):
            if c.natural_frequency_hz == 0.0 and not any(k.natural_frequency_hz == 0.0 for k in out):
                out.insert(0, c)   # a rigid-body slope the coarse bins below the first peak were too few to show
            elif c.natural_frequency_hz > 0.0 and all(
                    abs(c.natural_frequency_hz / k.natural_frequency_hz - 1.0) > 0.15
                    for k in out if k.natural_frequency_hz > 0.0):
                out.append(c)
    return out


SLOW_DECAY = 1e-6  # a free-response pole still above this fraction of its start where the held-out data begin


def slow_free_response(thetas, structures, rate_hz: float, controller, input_delay: int, n: int,
                       split: int) -> tuple[np.ndarray, int]:
    """``(n, d)`` free responses ``Re lambda^k``, ``Im lambda^k`` of the stable poles of the model's autonomous loop
    (closed loop: plant, delay line and controller, :func:`.filters.closed_loop_matrix`; open loop: the plant)
    that are still above ``SLOW_DECAY`` of their start at sample ``split``, and the first sample from which the
    other poles have decayed below 1e-3. A record cut from a running loop starts in a state the model, simulated
    from rest, does not have; its free response is the output error's first part and, for a slow pole, lasts
    into the held-out data: a PI controller's integrator state behind a square-wave level, a closed-loop pole
    at 0.99998 (a 14 s decay at 4096 Hz), made the true model's held-out error 900 times its noise. Integrators
    (``|lambda| = 1``) are left out (open loop: :func:`.offline.integrator_free_response`)."""
    from ..estimation.filters import closed_loop_matrix, total_model_discrete

    plant = total_model_discrete(list(thetas), list(structures), 1.0 / rate_hz)
    if controller is not None:
        mat = closed_loop_matrix(plant, controller, input_delay)
        if not isinstance(mat, np.ndarray):     # over DENSE_MAX_DIM states (a long delay line): left out
            return np.zeros((n, 0)), 0
        lam = np.linalg.eigvals(mat)
    else:
        lam = np.linalg.eigvals(plant.phi) if plant.phi.size else np.zeros(0)
    mod = np.abs(lam)
    stable = (mod > 0.0) & (mod < 1.0 - 1e-12)
    slow = stable & (mod ** max(split, 1) > SLOW_DECAY) & (lam.imag >= 0.0)
    fast = stable & ~slow
    skip = int(np.ceil(np.max(np.log(1e-3) / np.log(mod[fast])))) if fast.any() else 0
    if not slow.any():
        return np.zeros((n, 0)), skip
    k = np.arange(n)[:, None]
    powers = np.exp(k * np.log(lam[slow].astype(complex))[None, :])
    cols = [powers.real] + ([powers[:, lam[slow].imag > 0].imag] if np.any(lam[slow].imag > 0) else [])
    return np.hstack(cols), min(skip, split // 2)


def _held_out_error(thetas, structures, rate_hz: float, u, y, r, controller, input_delay: int,
                    split: int) -> tuple[float, float, np.ndarray]:
    """Mean squared output error of the model on ``[:split]`` (fit) and ``[split:]`` (held out), and the held-out
    output error itself (for :func:`_significant_gain`): :func:`_output_error`."""
    e = _output_error(thetas, structures, rate_hz, u, y, r, controller, input_delay, split)
    if e is None:
        return np.inf, np.inf, np.full(np.asarray(y).size - split, np.inf)
    return float(np.mean(e[:split] ** 2)), float(np.mean(e[split:] ** 2)), e[split:]


def _output_error(thetas, structures, rate_hz: float, u, y, r, controller, input_delay: int,
                  split: int) -> np.ndarray | None:
    """The model's output error (None when not finite). The model is simulated from rest; the free response of its
    slow poles (:func:`slow_free_response`), fitted on ``[:split]``, is taken out of the whole error."""
    if controller is not None:
        from ..estimation.filters import closed_loop_response
        _, y_hat = closed_loop_response(list(thetas), list(structures), 1.0 / rate_hz, controller, r, input_delay)
    else:
        from ..plant import open_loop_output
        y_hat = open_loop_output(list(thetas), list(structures), rate_hz, u, input_delay)
    e = y - y_hat
    if not np.all(np.isfinite(e)):
        return None
    integrators = max((st.integrators for st in structures), default=0)
    if integrators and controller is None:   # open loop: a rigid body keeps the plant's initial state for ever
        from .offline import integrator_free_response
        q = integrator_free_response(e.size, integrators, 1.0 / rate_hz)
        e = e - q @ (q.T @ e)
    basis, skip = slow_free_response(thetas, structures, rate_hz, controller, input_delay, e.size, split)
    if basis.shape[1] and split - skip > 2 * basis.shape[1]:
        coef = np.linalg.lstsq(basis[skip:split], e[skip:split], rcond=None)[0]
        e = e - basis @ coef
    return e


def _start(candidates: list[Candidate], K: int) -> list[Candidate] | None:
    """The rigid body (if any) plus the most prominent peaks, K submodels in all, rigid first then by frequency."""
    rigid = [c for c in candidates if c.natural_frequency_hz == 0.0]
    peaks = [c for c in candidates if c.natural_frequency_hz > 0.0]
    n_peaks = K - len(rigid)
    if n_peaks < 0 or n_peaks > len(peaks) or K < 1:
        return None
    return rigid + sorted(peaks[:n_peaks], key=lambda c: c.natural_frequency_hz)


def _stabilized(start: list[Candidate], rate_hz: float, controller, input_delay: int) -> list[Candidate]:
    """A start the controller stabilizes (the closed-loop instrument, [A-SRIVC] eq. 20, needs one): peak-picked damping
    is resolution-limited and the gain follows from it, so a start may destabilize a loop with a small margin; the
    damping of every resonant candidate is doubled (at most 0.7) until it is stable, then the gains are halved."""
    if controller is None:
        return start
    from ..estimation.filters import closed_loop_radius

    def stable(cands: list[Candidate]) -> bool:
        try:
            return closed_loop_radius([c.theta() for c in cands], [c.structure for c in cands], 1.0 / rate_hz,
                                      controller, input_delay) < 1.0
        except ValueError:
            return False

    cands = list(start)
    for step in range(8):
        if stable(cands):
            return cands
        if step < 4:
            cands = [c if c.natural_frequency_hz == 0 else Candidate(
                c.natural_frequency_hz, min(2.0 * c.damping_ratio, 0.7), c.gain, c.prominence_decades, c.integrators)
                for c in cands]
        else:
            cands = [Candidate(c.natural_frequency_hz, c.damping_ratio, 0.5 * c.gain, c.prominence_decades,
                               c.integrators) for c in cands]
    return cands  # still unstable: identify reports it


def _nested_start(best_fit: Any, candidates: list[Candidate], K: int, skip: int = 0) -> list[Candidate] | None:
    """Start for order K from the best smaller model: its fitted submodels plus the most prominent candidates not
    within 15 % of one of its modes (the last one replaced by the ``skip``-th next: alternatives). A fit may have
    moved a start to a mode the peak list ranked low, e.g. a well-damped low mode that dominates the output error."""
    fitted = _fitted_candidates(best_fit)
    need = K - len(fitted)
    if need < 1:
        return None
    has_rigid = any(c.natural_frequency_hz == 0.0 for c in fitted)
    fresh = [c for c in candidates
             if (c.natural_frequency_hz == 0.0 and not has_rigid)
             or (c.natural_frequency_hz > 0.0 and all(abs(c.natural_frequency_hz / m.natural_frequency_hz - 1.0) > 0.15
                                                      for m in fitted if m.natural_frequency_hz > 0.0))]
    if len(fresh) < need + skip:
        return None
    return sorted(fitted + fresh[:need - 1] + [fresh[need - 1 + skip]], key=lambda c: c.natural_frequency_hz)


def _fitted_candidates(fit: Any) -> list[Candidate]:
    out = []
    for t, s in zip(fit.thetas, fit.structures, strict=True):
        f, z, g = modal_from_theta(t, s) if s.n == 2 else (0.0, 0.0, t[0])
        out.append(Candidate(f, z, g, 0.0, s.integrators))
    return out


def _residual_start(best_fit: Any, frf: FRFEstimate, K: int, input_delay: int,
                    frequency_range_hz: tuple[float, float] | None, G_model: np.ndarray) -> list[Candidate] | None:
    """Start for order K = K_fit + 1 from where the best smaller model misfits: the resonance of the residual FRF
    ``G - G_model`` (same validity, noise and prominence tests as the peaks), not within 15 % of a fitted mode,
    that carries the most output power. A well-damped mode beside a stronger one shows no peak of its own in ``G``
    but does in the residual, once the stronger one is modelled (step 2 of ``core/identification/adequacy.py``, used
    to build).
    ``G_model``: that model's FRF on the bins (:func:`.frf.model_frf_on_bins`)."""
    fitted = _fitted_candidates(best_fit)
    if K - len(fitted) != 1:
        return None
    new = [c for c in find_candidates(replace(frf, G=frf.G - G_model), input_delay, frequency_range_hz)
           if c.natural_frequency_hz > 0.0 and all(abs(c.natural_frequency_hz / m.natural_frequency_hz - 1.0) > 0.15
                                                   for m in fitted if m.natural_frequency_hz > 0.0)]
    if not new:
        return None
    # the largest share of the output: a mode's response power under flat excitation ~ gain^2 f_n / zeta
    best = max(new, key=lambda c: c.gain ** 2 * c.natural_frequency_hz / max(c.damping_ratio, 1e-6))
    return sorted(fitted + [best], key=lambda x: x.natural_frequency_hz)


def _rigid_start(best_fit: Any, candidates: list[Candidate], frf: FRFEstimate, K: int,
                 input_delay: int) -> list[Candidate] | None:
    """A rigid body ``b0/p^2`` the slope test could not see (closed loop: below the first mode a square wave
    excites only its few lines), with ``b0 = -Re G omega^2`` at the lowest valid bins, plus the best smaller model
    (or, for K = 1, nothing else); None when a rigid body is already a candidate or fitted."""
    if any(c.natural_frequency_hz == 0.0 for c in candidates):
        return None
    fitted = _fitted_candidates(best_fit) if best_fit is not None else []
    if any(c.natural_frequency_hz == 0.0 for c in fitted) or K - len(fitted) != 1:
        return None
    k = np.flatnonzero(frf.valid & (frf.freqs_hz > 0.0))[:3]
    if k.size == 0:
        return None
    g = _compensated(frf, input_delay)[k]
    b0 = float(np.median(-np.real(g) * (TWO_PI * frf.freqs_hz[k]) ** 2))
    if not b0 > 0.0:
        return None
    return [Candidate(0.0, 0.0, b0, 0.0, 2)] + fitted


class _FrfObjective:
    """Weighted misfit of the additive continuous-time model of a candidate list on the FRF (:func:`refine_on_frf`):
    ``G`` with the delay and the hold's half sample removed, the valid leakage-free bins, each weighted by its
    uncertainty; parameters ``ln omega, ln zeta, b0`` per mode, ``b0`` per rigid body."""

    def __init__(self, template: list[Candidate], frf: FRFEstimate, input_delay: int) -> None:
        ok = frf.valid & (frf.freqs_hz > 0.0) & np.isfinite(frf.uncertainty) & (frf.uncertainty > 0.0)
        if frf.leakage is not None:
            ok &= ~frf.leakage
        self.template, self.rate_hz, self.n_bins = template, frf.rate_hz, int(ok.sum())
        self.resolution_hz = frf.resolution_hz
        self.s = 1j * TWO_PI * frf.freqs_hz[ok]
        self.target = _compensated(frf, input_delay)[ok]
        self.weight = 1.0 / frf.uncertainty[ok]
        self.n_par = sum(1 if c.natural_frequency_hz == 0.0 else 3 for c in template)

    def x0(self, cands: list[Candidate]) -> np.ndarray:
        x: list[float] = []
        for c in cands:
            x += [c.gain] if c.natural_frequency_hz == 0.0 else [
                np.log(TWO_PI * c.natural_frequency_hz), np.log(max(c.damping_ratio, 1e-4)), c.gain]
        return np.array(x)

    def residual(self, x: np.ndarray) -> np.ndarray:
        g, k, s = np.zeros(self.s.size, dtype=complex), 0, self.s
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            for c in self.template:
                if c.natural_frequency_hz == 0.0:
                    g += x[k] / s ** c.integrators
                    k += 1
                else:
                    q = s / np.exp(np.clip(x[k], -50.0, 50.0))
                    g += x[k + 2] / (1.0 + 2.0 * np.exp(np.clip(x[k + 1], -50.0, 50.0)) * q + q * q)
                    k += 3
            e = (g - self.target) * self.weight
        e = np.concatenate([e.real, e.imag])
        return np.where(np.isfinite(e), e, 1e150)

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        """``d residual / d x`` (analytic; with ``D = 1 + 2 zeta q + q^2``, ``q = s/omega``: ``dT/d ln omega =
        b q (2 zeta + 2 q)/D^2``, ``dT/d ln zeta = -2 b zeta q/D^2``, ``dT/db = 1/D``; a rigid body ``1/s^l``)."""
        s = self.s
        jac = np.zeros((s.size, x.size), dtype=complex)
        k = 0
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            for c in self.template:
                if c.natural_frequency_hz == 0.0:
                    jac[:, k] = 1.0 / s ** c.integrators
                    k += 1
                    continue
                q = s / np.exp(np.clip(x[k], -50.0, 50.0))
                zeta, b = np.exp(np.clip(x[k + 1], -50.0, 50.0)), x[k + 2]
                d = 1.0 + 2.0 * zeta * q + q * q
                jac[:, k] = b * q * (2.0 * zeta + 2.0 * q) / (d * d)
                jac[:, k + 1] = -2.0 * b * zeta * q / (d * d)
                jac[:, k + 2] = 1.0 / d
                k += 3
            jac *= self.weight[:, None]
        out = np.vstack([jac.real, jac.imag])
        return np.where(np.isfinite(out), out, 0.0)

    def candidates(self, x: np.ndarray) -> list[Candidate] | None:
        out, k = [], 0
        for c in self.template:
            if c.natural_frequency_hz == 0.0:
                out.append(Candidate(0.0, 0.0, float(x[k]), c.prominence_decades, c.integrators))
                k += 1
                continue
            if not (abs(x[k]) < 50.0 and abs(x[k + 1]) < 50.0):   # ran off (exp would overflow)
                return None
            f, zeta = float(np.exp(x[k])) / TWO_PI, float(np.exp(x[k + 1]))
            if not (0.0 < f < 0.5 * self.rate_hz and zeta < 5.0):
                return None
            if 2.0 * zeta * f < DEGENERATE_BAND_BINS * self.resolution_hz:
                return None   # a line through one bin's noise, no mode
            out.append(Candidate(f, zeta, float(x[k + 2]), c.prominence_decades, 0))
            k += 3
        return out


def refine_on_frf(start: list[Candidate], frf: FRFEstimate, input_delay: int,
                  ftol: float = 1e-8) -> tuple[list[Candidate], float] | None:
    """The start refined on the FRF and its weighted misfit: the additive continuous-time model ``sum_i b0_i /
    (1 + 2 zeta_i s/omega_i + (s/omega_i)^2)`` (a rigid body ``b0/s^l``) fitted to ``G`` by weighted nonlinear least
    squares (Levenberg-Marquardt, :class:`_FrfObjective`). A peak-read or a smaller model's mode is biased where the
    start lacks a mode that the data have (a K - 1 fit compensates it in the time domain, weighted by the output's
    power); on the FRF each bin counts by its own accuracy. None when the fit fails, does not halve the weighted
    misfit, leaves a mode outside ``(0, Nyquist)`` or one with a half-power band ``2 zeta f`` below
    :data:`DEGENERATE_BAND_BINS` of a bin (a degenerate fit of one bin's noise: a 3.9 Hz "mode" with zeta 2.5e-6
    then let a third mode in at a 2.0 % gain; half a bin of the finest FRF was too strict: a real 6.1 Hz mode with
    zeta 0.005 was lost). ``ftol``: the least-squares stop on the relative fall of the misfit per step."""
    from scipy.optimize import least_squares

    obj = _FrfObjective(start, frf, input_delay)
    if obj.n_bins < obj.n_par:
        return None
    x0 = obj.x0(start)
    try:
        sol = least_squares(obj.residual, x0, jac=obj.jacobian, method="lm", max_nfev=20 * (obj.n_par + 1),
                            ftol=ftol)
    except (ValueError, np.linalg.LinAlgError):
        return None
    cost = 2.0 * float(sol.cost)
    if not np.all(np.isfinite(sol.x)) or not cost < 0.5 * float(np.sum(obj.residual(x0) ** 2)):
        return None
    out = obj.candidates(sol.x)
    return None if out is None else (out, cost)


def _with_frf_refined(starts: list[list[Candidate]], frf: FRFEstimate, input_delay: int,
                      ftol: float = 1e-8) -> Iterator[list[Candidate]]:
    """The starts of one order refined on the FRF (:func:`refine_on_frf`, where it succeeds), then as read: the
    refined ones first, as they more often lead the time-domain fit to the modes. Lazily: a start is refined only
    when the scan gets to it (it stops at the first start that gains; refining all of them first spent 1.2 s on two
    refinements after which the first refined start had already won, ``validate_autostart.py --timing`` plant 6)."""
    for st in starts:
        ref = refine_on_frf(st, frf, input_delay, ftol)
        if ref is not None:
            yield ref[0]
    yield from starts


def _same_start(a: list[Candidate], b: list[Candidate]) -> bool:
    return len(a) == len(b) and all(
        x.integrators == y.integrators and (x.natural_frequency_hz == y.natural_frequency_hz == 0.0 or (
            y.natural_frequency_hz > 0.0 and abs(x.natural_frequency_hz / y.natural_frequency_hz - 1.0) <= 0.15))
        for x, y in zip(a, b, strict=True))


def _fit(u, y, rate_hz, r, controller, input_delay, start: list[Candidate], max_iterations: int,
         tol: float = FINAL_TOL, settle_tol: float | None = None, settle_floor: float = 0.0):
    """Offline additive (CL)SRIVC from the candidates. In closed loop, a start the controller does not stabilize
    even after :func:`_stabilized` is first refined by the open-loop additive SRIVC (u -> y; biased by the feedback
    but needs no stable closed loop), whose result then starts the CLSRIVC."""
    from ..estimation.filters import ClosedLoopUnstableError
    from .offline import identify

    start = _stabilized(start, rate_hz, controller, input_delay)
    structures = [c.structure for c in start]
    thetas = [c.theta() for c in start]
    try:
        return identify(u, y, rate_hz, structures, thetas, r=r, controller=controller, input_delay=input_delay,
                        max_iterations=max_iterations, tol=tol, settle_tol=settle_tol,
                        settle_floor=settle_floor)
    except ClosedLoopUnstableError:
        if controller is None:
            raise
    pre = identify(u, y, rate_hz, structures, thetas, input_delay=input_delay, max_iterations=max_iterations,
                   method="additive-srivc", tol=tol, settle_tol=settle_tol, settle_floor=settle_floor)
    return identify(u, y, rate_hz, structures, pre.thetas, r=r, controller=controller, input_delay=input_delay,
                    max_iterations=max_iterations, tol=tol, settle_tol=settle_tol, settle_floor=settle_floor)


def _refit_worse(full: Any, scan: Any, u, y, rate_hz: float, r, controller, input_delay: int,
                 margin: float) -> tuple[float, float] | None:
    """``(refit's, scan fit's)`` mean squared output error on the whole record (:func:`_output_error`, simulated
    from rest, the slow poles' free response taken out) when the whole-record refit is more than ``margin`` worse
    than the scan's fit it started from, else None. The refit only adds the held-out samples to the same model; one
    that ends elsewhere is another optimum, not a refinement (a 7 + 142 Hz plant cut in motion, one rounding path in
    eight: the refit ran from the right modes to 0.15 Hz zeta 1.0 and 2.9 Hz zeta 4.8, nearly converged)."""
    def mse(fit: Any) -> float:
        e = _output_error(fit.thetas, fit.structures, rate_hz, u, y, r, controller, input_delay, np.asarray(y).size)
        return np.inf if e is None else float(np.mean(e ** 2))

    e_full, e_scan = mse(full), mse(scan)
    return None if e_full <= (1.0 + margin) * e_scan else (e_full, e_scan)


def _usable(res: Any, rate_hz: float) -> bool:
    """Finite, every resonant submodel stable and below the Nyquist frequency (a fit that ran off there, e.g. a
    well-damped mode near the top of the band, describes nothing the samples can show)."""
    return all(np.all(np.isfinite(t)) for t in res.thetas) and all(
        t[0] > 0 and t[1] > 0 and modal_from_theta(t, s)[0] < 0.5 * rate_hz
        for t, s in zip(res.thetas, res.structures, strict=True) if s.n == 2)


def _evaluate(K: int, start: list[Candidate], u, y, rate_hz, r, controller, input_delay, split: int,
              max_iterations: int, to_beat: Any = None, margin: float = DEFAULT_MARGIN) -> tuple[OrderRow, Any]:
    """Fit one start on ``[:split]`` and measure its output error on both parts (a failure is a row, not a crash).
    ``to_beat``: the smaller order's fit, when it fits its FRF (:func:`.frf_misfit.fits_its_frf`); while this fit's
    output error on ``[:split]`` is not ``margin`` below that fit's, it ends once its output error has settled
    (``SCAN_SETTLE``: one mode too many, the usual case of the order after the right one, stops in a few iterations
    instead of running to the limit). Not when the smaller model misfits the FRF: a fit whose output error sat flat
    for 3 iterations while a meaningless mode of the smaller fit (1949 Hz, zeta 106) moved to the missing 8.5 Hz
    mode then fell 1400-fold (``validate_autostart.py`` plant 8)."""
    settle, floor = None, 0.0
    if to_beat is not None and not to_beat.extra.get("reduced") and np.isfinite(to_beat.cost):
        settle, floor = SCAN_SETTLE, (1.0 - margin) * float(to_beat.cost)
    try:
        res = _fit(u[:split], y[:split], rate_hz, None if r is None else r[:split], controller, input_delay,
                   start, min(max_iterations, SCAN_MAX_ITERATIONS), SCAN_TOL, settle, floor)
    except Exception as exc:  # noqa: BLE001 - a failed order is a row of the table, not a crash
        return OrderRow(K, np.inf, np.inf, message=f"{type(exc).__name__}: {exc}"), None
    if not _usable(res, rate_hz):
        return OrderRow(K, np.inf, np.inf, converged=bool(res.converged), message="unstable or non-finite"), None
    try:
        e_fit, e_val, resid = _held_out_error(res.thetas, res.structures, rate_hz, u, y, r, controller, input_delay,
                                              split)
    except Exception as exc:  # noqa: BLE001 - e.g. the controller does not stabilize the fitted model
        return OrderRow(K, np.inf, np.inf, converged=bool(res.converged), message=f"{type(exc).__name__}: {exc}"), None
    return OrderRow(K, e_fit, e_val, converged=bool(res.converged), message=res.message, residual=resid), res


def _reduced(res: Any, j: int) -> Any:
    """The fit ``res`` without its submodel ``j`` (parameters, covariance blocks and modal rows of the others; not
    converged: a start, or a fallback when the refit fails)."""
    keep = [i for i in range(len(res.thetas)) if i != j]
    sizes = [t.size for t in res.thetas]
    offsets = np.concatenate([[0], np.cumsum(sizes)])
    idx = np.concatenate([np.arange(offsets[i], offsets[i + 1]) for i in keep])

    def pick(a: Any) -> Any:
        return np.asarray(a)[np.ix_(idx, idx)] if np.ndim(a) == 2 and np.shape(a)[0] == offsets[-1] else a
    return replace(res, structures=[res.structures[i] for i in keep], thetas=[res.thetas[i] for i in keep],
                   covariances=[res.covariances[i] for i in keep], covariance=pick(res.covariance), P=pick(res.P),
                   p_blocks=[res.p_blocks[i] for i in keep], modal=np.asarray(res.modal)[keep],
                   modal_std=np.asarray(res.modal_std)[keep], converged=False,
                   message=f"the K = {len(keep) + 1} fit without its submodel {j + 1}",
                   extra={**res.extra, "reduced": True})   # cost: still the K + 1 fit's


def _least_relevant(res: Any, u, y, rate_hz: float, r, controller, input_delay: int,
                    split: int) -> tuple[int, float, float, np.ndarray] | None:
    """Backward check of a fit with more than one submodel: the submodel whose removal raises the held-out output
    error least, as ``(index, fit error, held-out error, held-out residual)`` of the reduced model (None for a
    single submodel). A reduction the controller does not stabilize counts as an infinite error."""
    if len(res.thetas) < 2:
        return None
    best: tuple[int, float, float, np.ndarray] | None = None
    for j in range(len(res.thetas)):
        keep = [i for i in range(len(res.thetas)) if i != j]
        try:
            e_fit, e_val, resid = _held_out_error([res.thetas[i] for i in keep], [res.structures[i] for i in keep],
                                                  rate_hz, u, y, r, controller, input_delay, split)
        except Exception:  # noqa: BLE001 - e.g. the loop is unstable without it: that submodel is relevant
            continue
        if np.isfinite(e_val) and (best is None or e_val < best[2]):
            best = (j, e_fit, e_val, resid)
    return best


def _beats(new: OrderRow, old: OrderRow, margin: float) -> bool:
    """The margin rule: ``new``'s held-out error is finite and below ``(1 - margin)`` times ``old``'s."""
    return bool(np.isfinite(new.validation_error) and new.validation_error < (1.0 - margin) * old.validation_error)


def _significant_gain(new: OrderRow, old: OrderRow, margin: float) -> bool:
    """Does ``new`` predict the held-out data better than ``old``? It must beat it by the margin (:func:`_beats`)
    and, when both held-out errors are known, the gain must hold throughout the held-out data: the log ratio of
    the two mean squared errors over each of ``HELD_OUT_BATCHES`` consecutive batches (correlated errors stay
    within a batch) has a mean above ``GAIN_T`` standard errors (Student t, one-sided 1 %). Measured on 5 s
    windows: a split mode beside a well-damped one gained 2.8 % on 1.5 s of held-out data with t = 1.1 (noise, not
    a mode); real modes gave t = 6 to 33. (The batch means of the squared-error difference were no good: one batch
    with a step of the square wave dominates them, t = 2.1 for a 700 000-fold gain.)"""
    if not _beats(new, old, margin):
        return False
    if not np.isfinite(old.validation_error):
        return True
    a, b = new.residual, old.residual
    if a is None or b is None or a.size != b.size or a.size < 2 * HELD_OUT_BATCHES:
        return True
    ratios = np.array([np.log(np.mean(bb * bb) / np.mean(aa * aa)) if np.any(aa) else np.inf
                       for aa, bb in zip(np.array_split(a, HELD_OUT_BATCHES), np.array_split(b, HELD_OUT_BATCHES),
                                         strict=True)])
    if not np.all(np.isfinite(ratios)):
        return bool(np.all(ratios > 0))
    sd = float(np.std(ratios, ddof=1))
    return bool(np.mean(ratios) > GAIN_T * sd / np.sqrt(HELD_OUT_BATCHES)) if sd > 0 else bool(np.mean(ratios) > 0)


def _choice(table: list[OrderRow], margin: float, paired: bool = True) -> OrderRow | None:
    """The order rule over the rows so far: from the smallest K that fitted, a larger K replaces the choice only if
    it is a significant gain over it (:func:`_significant_gain`; ``paired=False``: the margin alone, the scan's
    stepping stone); redundant rows are never chosen."""
    gain = _significant_gain if paired else _beats
    chosen: OrderRow | None = None
    for row in table:
        if not row.redundant and np.isfinite(row.validation_error) and (chosen is None or gain(row, chosen, margin)):
            chosen = row
    return chosen


def order_table(u, y, rate_hz: float, r, controller, input_delay: int, candidates: list[Candidate],
                orders: list[int], validation_fraction: float, max_iterations: int,
                margin: float, frf: FRFEstimate | None = None,
                frequency_range_hz: tuple[float, float] | None = None) -> tuple[list[OrderRow], dict[int, Any]]:
    """Fit each order on the first part, held-out error on the rest; mark the accepted order (module rule). A larger
    order built on the best smaller model tries up to ``ALTERNATIVES`` new peaks and, with ``frf``, the strongest
    resonance of that model's residual FRF (:func:`_residual_start`), and keeps the best."""
    n = u.size
    split = int(round(n * (1.0 - validation_fraction)))
    table: list[OrderRow] = []
    fits: dict[int, Any] = {}
    for K in orders:
        # the scan builds on the best model by the margin alone (a gain the paired test does not confirm can still be
        # the stepping stone to a larger order that is one); the paired test decides the order at the end
        chosen = _choice(table, margin, paired=False)
        best_fit = fits[chosen.K] if chosen is not None else None
        misses = len(table) - 1 - table.index(chosen) if chosen is not None else 0
        if misses >= STOP_AFTER_MISSES:  # larger K are not tried
            table.append(OrderRow(K, np.inf, np.inf, message=f"not tried ({misses} orders in a row without gain)"))
            continue
        tried = ([_start(candidates, K)] if best_fit is None else
                 [_nested_start(best_fit, candidates, K, skip) for skip in range(ALTERNATIVES)])
        starts = [st for st in tried if st is not None]
        # the smaller model's FRF on the bins: its residual gives a start, and whether it fits decides `quick`
        G_best = model_frf_on_bins(frf, best_fit.thetas, best_fit.structures, input_delay) \
            if best_fit is not None and frf is not None else None
        if G_best is not None and frf is not None:
            extra = _residual_start(best_fit, frf, K, input_delay, frequency_range_hz, G_best)
            if extra is not None and not any(_same_start(extra, st) for st in starts):
                starts.append(extra)
        if frf is not None and controller is not None:
            extra = _rigid_start(best_fit, candidates, frf, K, input_delay)
            if extra is not None:
                starts.append(extra)
        if not starts:
            table.append(OrderRow(K, np.inf, np.inf, message="fewer candidates than K"))
            continue
        # the model to beat already fits the FRF: the added mode has nothing to fit but noise, so its starts' FRF
        # refinement and its fits stop once their misfit no longer falls (QUICK_FRF_FTOL, SCAN_SETTLE)
        quick = G_best is not None and frf is not None and fits_its_frf(frf, G_best)
        runs: Iterable[list[Candidate]] = starts
        if frf is not None and FRF_REFINE:
            runs = _with_frf_refined(starts, frf, input_delay, QUICK_FRF_FTOL if quick else 1e-8)
        row: OrderRow | None = None
        res = None
        for st in runs:
            cand_row, cand_res = _evaluate(K, st, u, y, rate_hz, r, controller, input_delay, split, max_iterations,
                                           best_fit if quick else None, margin)
            if row is None or cand_row.validation_error < row.validation_error:
                row, res = cand_row, cand_res
            if chosen is not None and _beats(row, chosen, margin):
                break  # a gain: no need to try the other peaks
        if res is not None:
            fits[K] = res
        assert row is not None   # starts is not empty: every start gives a row
        table.append(row)
        if res is not None and chosen is not None and _beats(row, chosen, margin):
            _check_relevance(table, fits, res, u, y, rate_hz, r, controller, input_delay, split, margin)
    chosen = _choice(table, margin)
    if chosen is not None:
        chosen.accepted = True
    for row in table:   # the evidence of each order: its kept fit's submodels (the stabilization figure)
        row.modes = _fitted_candidates(fits[row.K]) if row.K in fits and np.isfinite(row.validation_error) else []
    return table, fits


def _check_relevance(table: list[OrderRow], fits: dict[int, Any], res: Any, u, y, rate_hz: float, r, controller,
                     input_delay: int, split: int, margin: float) -> None:
    """An order's gain must come from its added mode, not from a better fit of the others (a smaller order's scan
    fit stopped early, or sat in a poorer optimum): when the last row's model is no significant gain
    (:func:`_significant_gain`) over itself without its least relevant submodel, the row is marked redundant and
    that reduction, a model of one order less, replaces the smaller order's row if it predicts better."""
    row = table[-1]
    least = _least_relevant(res, u, y, rate_hz, r, controller, input_delay, split)
    if least is None:
        return
    j, e_fit, e_val, resid = least
    if _significant_gain(row, OrderRow(row.K - 1, e_fit, e_val, residual=resid), margin):
        return
    f_j = _fitted_candidates(res)[j].natural_frequency_hz
    what = f"{f_j:.4g} Hz mode" if f_j > 0.0 else "rigid body"
    row.redundant = True
    row.message += f"; without its {what} no significant loss on held-out data: not a gain of order"
    prev = next((t for t in table if t.K == row.K - 1), None)   # the scan has a row for every smaller order
    if prev is None or not e_val < prev.validation_error:
        return
    fits[row.K - 1] = _reduced(res, j)
    prev.fit_error, prev.validation_error, prev.converged, prev.redundant = e_fit, e_val, False, False
    prev.residual = resid
    prev.message = f"K = {row.K} fit without its {what} (predicts better than this order's own fit); was: " \
        + prev.message


def find_modes(u, y, rate_hz: float, *, r=None, controller=None, input_delay: int = 0, count: int = 0,
               max_count: int = 6, frequency_range_hz: tuple[float, float] | None = None,
               validation_fraction: float = 0.3, margin: float = DEFAULT_MARGIN,
               max_iterations: int = 30, frf: FRFEstimate | None = None,
               refit_tol: float = FINAL_TOL) -> ModeFindResult:
    """Find the modes (``count`` of them, or the order by held-out error when ``count`` is 0); the chosen order is
    refitted on the whole record to ``refit_tol``. Raises ``ValueError`` when the data contain no usable candidate
    or no order could be fitted."""
    u = np.asarray(u, dtype=float)
    y = np.asarray(y, dtype=float)
    r = None if r is None or controller is None else np.asarray(r, dtype=float)
    if not 0.05 <= validation_fraction <= 0.8:
        raise ValueError(f"validation_fraction must be in [0.05, 0.8], got {validation_fraction}")
    if count < 0 or max_count < 1:
        raise ValueError("need count >= 0 and max_count >= 1")
    frf = estimate_frf(u, y, rate_hz, r) if frf is None else frf
    candidates = finer_candidates(u, y, rate_hz, r, frf, input_delay, frequency_range_hz,
                                  find_candidates(frf, input_delay, frequency_range_hz))
    if not candidates and (controller is None or _rigid_start(None, [], frf, 1, input_delay) is None):
        # (closed loop: a rigid body whose slope the few lowest bins could not show is still tried, K = 1 first)
        raise ValueError("no resonance or rigid-body behaviour found in the valid FRF band "
                         f"({frf.band_hz}): the data do not excite the plant enough to find modes")
    orders = [count] if count > 0 else list(range(1, max_count + 1))  # the residual FRF may add candidates
    table, fits = order_table(u, y, rate_hz, r, controller, input_delay, candidates, orders, validation_fraction,
                              max_iterations, margin, frf, frequency_range_hz)
    chosen = next((row for row in table if row.accepted), None)
    if chosen is None:
        raise ValueError("no model order could be fitted: " + "; ".join(f"K={t.K}: {t.message}" for t in table))
    res = fits[chosen.K]
    start = _fitted_candidates(res)
    message = f"K = {chosen.K} by held-out output error (margin {margin:.0%})"
    try:
        full = _fit(u, y, rate_hz, r, controller, input_delay, start, max_iterations, refit_tol)
        if not (_usable(full, rate_hz) and fit_usable(full)):
            message += "; refit on the whole record unstable or not converged: kept the fit on the first part"
        elif (worse := _refit_worse(full, res, u, y, rate_hz, r, controller, input_delay, margin)) is not None:
            message += (f"; refit on the whole record fits it worse (output error {worse[0]:.3g} against "
                        f"{worse[1]:.3g}): kept the fit on the first part")
        else:
            res = full
    except Exception as exc:  # noqa: BLE001
        message += f"; refit on the whole record failed ({type(exc).__name__}): kept the fit on the first part"
    structures = list(res.structures)
    modal = np.array([modal_from_theta(t, s) for t, s in zip(res.thetas, structures, strict=True)])
    band = frf.band_hz
    ident = [bool(s.n == 0 or (band is not None and band[0] <= m[0] <= band[1]))
             for m, s in zip(modal, structures, strict=True)]
    if not all(ident):
        message += "; mode(s) outside the excited band are not identifiable: " + ", ".join(
            f"{m[0]:.4g} Hz" for m, ok in zip(modal, ident, strict=True) if not ok)
    return ModeFindResult(chosen.K, structures, [np.asarray(t, float) for t in res.thetas], modal, ident, table,
                          frf, candidates, res, message)


def autostart_config(cfg: SettingsT, r, u, y, count: int | None = None,
                     refit_tol: float = FINAL_TOL) -> tuple[SettingsT, ModeFindResult]:
    """The automatic start of a :class:`config.MonitorConfig` without guesses: modes found on the given
    data (the longest finite stretch; ``count`` None: ``modes.count``), returned as the configuration with those
    modes as guesses, and the evidence. ``refit_tol``: see :func:`find_modes` (the pipeline passes
    :data:`SCAN_TOL`: its estimator's offline initialization refines the start on the same samples right after).
    Raises ``ValueError`` (one line) when no mode can be found."""
    closed = bool(cfg.closed_loop)
    r = np.asarray(r, dtype=float) if closed and r is not None else None
    u, y = np.asarray(u, dtype=float), np.asarray(y, dtype=float)
    seg = longest_finite(r, u, y)
    k = cfg.mode_count if count is None else int(count)
    res = find_modes(u[seg], y[seg], cfg.loop_rate_hz, r=None if r is None else r[seg],
                     controller=cfg.controller if closed else None, input_delay=cfg.input_delay_samples, count=k,
                     max_count=max(cfg.max_mode_count, k), frequency_range_hz=cfg.frequency_range_hz,
                     max_iterations=max(30, cfg.estimator.init_max_iterations), refit_tol=refit_tol)
    modal = np.array([m if s.n == 2 else (0.0, 0.0, m[2]) for m, s in zip(res.modal, res.structures, strict=True)])
    order = np.argsort(modal[:, 0], kind="stable")   # modes numbered by frequency (rigid body first), as users do
    return cfg.with_modes(modal[order], [res.structures[i].integrators for i in order]), res
