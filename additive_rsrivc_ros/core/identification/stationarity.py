"""Is an offline record stationary? Fit its consecutive segments, compare them, fit the stationary parts separately.

A record whose plant changed part-way has no single model: one fit over all of it compromises between the parts, and
with a close pair of modes it can split a mode in two with opposite gains. :func:`identify_segments` cuts the record
into at most :data:`MAX_SEGMENTS` equal segments of at least :data:`MIN_SEGMENT_S`, fits each (filters warmed up on
the samples before it: the segments' estimates are independent) and grows stationary runs from the first segment: a
segment joins the run unless a modal quantity (frequency, damping, gain) differs from the run's inverse-variance
mean by more than ``z_crit`` stds of the difference AND by the relevant change ``faults.min_change.*`` (the stds alone
are too small where coloured noise or a fit's bias dominates: healthy open-loop multisine and rigid-body records
reach 8 and 16 sigma between segments, far below a relevant change; scripts/study_stationarity.py). ``z_crit``: the
two-sided normal quantile at ``alpha / (2 T)``, ``T`` comparisons (Bonferroni: a stationary record is called
non-stationary with probability at most ``alpha``). Each run is then fitted on its own samples from its segments'
mean. A record shorter than two segments is not tested.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from statistics import NormalDist
from typing import Any

import numpy as np

from ..model import SubmodelStructure
from .offline.stable import WARMUP_DECAY_TIMES, fit_usable, slowest_decay_rate
from .offline.types import IdentificationResult

MIN_SEGMENT_S = 20.0      # a segment is at least this long ...
MIN_SEGMENT_WARMUPS = 4.0  # ... and this many filter warm-ups (WARMUP_DECAY_TIMES decay times of the slowest mode)
MAX_SEGMENTS = 6
ALPHA = 0.01              # family-wise probability of calling a stationary record non-stationary
QUANTITY_NAMES = ("natural_frequency", "damping", "gain")
MODAL_KEYS = ("natural_frequency_hz", "damping_ratio", "gain")

#: ``fit(a, b, warmup, thetas0)``: the identification of samples ``[a - warmup, b)`` of the record whose first
#: ``warmup`` samples only warm up the filters (``warmup`` None: the estimator's own rule), started at ``thetas0``
SegmentFit = Callable[[int, int, int | None, Sequence[np.ndarray]], IdentificationResult | None]


@dataclass
class Change:
    """A modal quantity that differs between two stationary parts (1-based mode)."""

    mode: int
    quantity: str
    before: float
    after: float
    before_std: float
    after_std: float
    at_s: float

    @property
    def relative_change(self) -> float:
        return (self.after - self.before) / abs(self.before) if self.before else float("nan")

    @property
    def z(self) -> float:
        return abs(self.after - self.before) / float(np.hypot(self.before_std, self.after_std))

    def text(self) -> str:
        return (f"mode {self.mode} {self.quantity.replace('_', ' ')} {100 * self.relative_change:+.2f} % "
                f"({self.before:.6g} ± {self.before_std:.2g} -> {self.after:.6g} ± {self.after_std:.2g}, "
                f"{self.z:.0f} sigma) at {self.at_s:.4g} s")

    def to_dict(self) -> dict[str, Any]:
        return {"mode": self.mode, "quantity": self.quantity, "at_s": self.at_s, "before": self.before,
                "before_std": self.before_std, "after": self.after, "after_std": self.after_std,
                "relative_change": self.relative_change, "z": self.z}


@dataclass
class Part:
    """A stretch of the record ``[start_s, end_s)`` (samples ``[a, b)``) and its fit."""

    a: int
    b: int
    start_s: float
    end_s: float
    result: IdentificationResult | None = None

    @property
    def usable(self) -> bool:
        return self.result is not None and fit_usable(self.result)

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"start_s": self.start_s, "end_s": self.end_s}
        if self.result is not None:
            r = self.result
            d.update(converged=bool(r.converged), iterations=int(r.iterations), usable=self.usable,
                     modes=[{k: float(m[q]) for q, k in enumerate(MODAL_KEYS)}
                            | {f"{k}_std": float(s[q]) for q, k in enumerate(MODAL_KEYS)}
                            for m, s in zip(r.modal, r.modal_std, strict=True)])
        return d


@dataclass
class Stationarity:
    """The test's outcome: ``stationary`` None when not tested (``message`` says why)."""

    stationary: bool | None
    message: str
    segments: list[Part] = field(default_factory=list)
    runs: list[Part] = field(default_factory=list)
    changes: list[Change] = field(default_factory=list)
    z_crit: float = float("nan")
    comparisons: int = 0
    chosen: int = -1              # index into runs of the part reported as the result
    segment_s: float = float("nan")   # a change lies within one segment length of its at_s

    def to_dict(self) -> dict[str, Any]:
        return {"stationary": self.stationary, "tested": self.stationary is not None, "message": self.message,
                "alpha": ALPHA, "z_crit": self.z_crit if self.comparisons else None, "comparisons": self.comparisons,
                "segment_s": self.segment_s if self.segments else None,
                "changes": [c.to_dict() for c in self.changes], "segments": [s.to_dict() for s in self.segments],
                "parts": [p.to_dict() for p in self.runs], "result_part": self.chosen if self.chosen >= 0 else None}


def warmup_s(thetas: Sequence[np.ndarray], structures: Sequence[SubmodelStructure]) -> float:
    """The filters' warm-up: :data:`WARMUP_DECAY_TIMES` decay times of the slowest mode of ``thetas``."""
    sigma = slowest_decay_rate(thetas, structures)
    return WARMUP_DECAY_TIMES / sigma if sigma > 0.0 else 0.0


def segment_bounds(n: int, rate_hz: float, warm_s: float) -> list[tuple[int, int]]:
    """Equal segments ``[a, b)`` of ``n`` samples, each at least :data:`MIN_SEGMENT_S` and
    :data:`MIN_SEGMENT_WARMUPS` warm-ups long, at most :data:`MAX_SEGMENTS`; ``[]`` when fewer than two fit."""
    min_len = max(MIN_SEGMENT_S, MIN_SEGMENT_WARMUPS * warm_s) * rate_hz
    m = min(MAX_SEGMENTS, int(n // min_len)) if min_len > 0 else MAX_SEGMENTS
    if m < 2:
        return []
    edges = np.linspace(0, n, m + 1).round().astype(int)
    return [(int(edges[i]), int(edges[i + 1])) for i in range(m)]


def z_threshold(comparisons: int, alpha: float = ALPHA) -> float:
    """Two-sided Bonferroni threshold of ``comparisons`` normal z tests at family-wise level ``alpha``."""
    return float(NormalDist().inv_cdf(1.0 - alpha / (2.0 * max(comparisons, 1))))


def _pooled(parts: Sequence[Part]) -> tuple[np.ndarray, np.ndarray]:
    """Inverse-variance mean of the parts' modal values and its std, ``(K, 3)`` each."""
    vals = np.array([p.result.modal for p in parts if p.result is not None])
    std = np.array([p.result.modal_std for p in parts if p.result is not None])
    with np.errstate(divide="ignore", invalid="ignore"):   # a quantity without a std (rigid body's 0 Hz): untested
        w = np.where(np.isfinite(std) & (std > 0), 1.0 / std**2, 0.0)
        tot = w.sum(axis=0)
        mean = np.where(tot > 0, (w * np.nan_to_num(vals)).sum(axis=0) / tot, vals.mean(axis=0))
        return mean, np.where(tot > 0, 1.0 / np.sqrt(tot), np.nan)


def _differences(run: Sequence[Part], seg: Part, z_crit: float, min_change: Sequence[float]) -> list[Change]:
    """The modal quantities of ``seg`` that differ from the run's mean significantly and relevantly."""
    mean, sd = _pooled(run)
    assert seg.result is not None
    val, vsd = seg.result.modal, seg.result.modal_std
    out = []
    for i in range(mean.shape[0]):
        for q in range(3):
            diff, s = val[i, q] - mean[i, q], float(np.hypot(sd[i, q], vsd[i, q]))
            if not (np.isfinite(diff) and np.isfinite(s) and s > 0):
                continue
            if abs(diff) > z_crit * s and abs(diff) > min_change[q] * abs(mean[i, q]):
                out.append(Change(i + 1, QUANTITY_NAMES[q], float(mean[i, q]), float(val[i, q]), float(sd[i, q]),
                                  float(vsd[i, q]), seg.start_s))
    return out


def _runs(segments: list[Part], z_crit: float, min_change: Sequence[float]) -> tuple[list[list[Part]], list[Change]]:
    """Stationary runs of consecutive usable segments and the changes between them."""
    runs: list[list[Part]] = []
    changes: list[Change] = []
    for seg in segments:
        if not seg.usable:
            continue
        diff = _differences(runs[-1], seg, z_crit, min_change) if runs else []
        if runs and not diff:
            runs[-1].append(seg)
        else:
            changes += diff
            runs.append([seg])
    return runs, changes


def identify_segments(fit: SegmentFit, n: int, rate_hz: float, thetas0: Sequence[np.ndarray],
                      structures: Sequence[SubmodelStructure], min_change: Sequence[float], t0_s: float = 0.0
                      ) -> tuple[Stationarity, Part | None, list[np.ndarray]]:
    """Test the record of ``n`` samples (first at ``t0_s``) for stationarity and fit its stationary parts
    (module docstring). Returns the test, the part to report (``None`` when stationary or not tested: the caller
    fits the whole record) and the start for the whole record's fit (the segments' mean when stationary, else
    ``thetas0``): the longest stationary part (the later one of equally long parts), fitted.
    ``min_change``: relevant relative changes of (frequency, damping, gain)."""
    warm = warmup_s(thetas0, structures)
    bounds = segment_bounds(n, rate_hz, warm)
    if not bounds:
        need = 2 * max(MIN_SEGMENT_S, MIN_SEGMENT_WARMUPS * warm)
        return Stationarity(None, f"stationarity not tested: record too short ({n / rate_hz:.4g} s; two segments of "
                            f"{need / 2:.4g} s needed)"), None, list(thetas0)
    w = int(round(warm * rate_hz))
    segments: list[Part] = []
    start = list(thetas0)
    for a, b in bounds:
        res = fit(a, b, min(w, a) if a else min(w, (b - a) // 4), start)
        seg = Part(a, b, t0_s + a / rate_hz, t0_s + b / rate_hz, res)
        segments.append(seg)
        if seg.usable and res is not None:
            start = res.thetas        # the next segment starts where this one ended: a few iterations
    usable = [s for s in segments if s.usable]
    comparisons = (len(usable) - 1) * 3 * len(thetas0)
    z_crit = z_threshold(comparisons)
    if len(usable) < 2:
        return Stationarity(None, f"stationarity not tested: only {len(usable)} of {len(segments)} segment fit(s) "
                            "usable", segments), None, list(thetas0)
    groups, changes = _runs(segments, z_crit, min_change)
    st = Stationarity(len(groups) == 1, "", segments, [], changes, z_crit, comparisons,
                      segment_s=(bounds[0][1] - bounds[0][0]) / rate_hz)
    if st.stationary:
        st.message = (f"stationary: {len(usable)} segments of {(bounds[0][1] - bounds[0][0]) / rate_hz:.4g} s agree "
                      f"(no modal quantity differs both by more than {z_crit:.2f} sigma and by its relevant change)")
        return st, None, _mean_thetas(usable)
    for g in groups:
        a, b = g[0].a, g[-1].b
        res = fit(a, b, None if a == 0 else min(w, a), _mean_thetas(g))
        st.runs.append(Part(a, b, g[0].start_s, g[-1].end_s, res))
    fitted = [j for j, p in enumerate(st.runs) if p.result is not None]
    what = f"NOT stationary: {'; '.join(c.text() for c in changes[:4])}" + (
        f" and {len(changes) - 4} more" if len(changes) > 4 else "")
    if not fitted:
        st.message = f"{what}; no stationary part could be fitted: the whole record is (a compromise)"
        return st, None, list(thetas0)
    st.chosen = max(fitted, key=lambda j: (st.runs[j].b - st.runs[j].a, j))
    part = st.runs[st.chosen]
    st.message = (f"{what}; its {len(st.runs)} stationary parts fitted separately, the result is the part "
                  f"[{part.start_s:.4g}, {part.end_s:.4g}) s (--start/--end choose another)")
    return st, part, list(thetas0)


def _mean_thetas(parts: Sequence[Part]) -> list[np.ndarray]:
    """The mean parameter vector of each submodel over the parts' fits (a start for their joint fit)."""
    fits = [p.result for p in parts if p.result is not None]
    return [np.mean([r.thetas[i] for r in fits], axis=0) for i in range(len(fits[0].thetas))]


def split_pairs(result: IdentificationResult) -> list[tuple[int, int]]:
    """Pairs of modes (1-based) that are one mode split in two: gains of opposite sign and natural frequencies
    closer than their half-power bandwidths together (or than 3 standard deviations of the difference)."""
    m, sd = np.asarray(result.modal, float), np.asarray(result.modal_std, float)
    out = []
    for i in range(m.shape[0]):
        for j in range(i + 1, m.shape[0]):
            if not (m[i, 0] > 0 and m[j, 0] > 0 and m[i, 2] * m[j, 2] < 0):
                continue
            width = abs(m[i, 1]) * m[i, 0] + abs(m[j, 1]) * m[j, 0]
            noise = 3.0 * float(np.hypot(sd[i, 0], sd[j, 0])) if np.isfinite(sd[[i, j], 0]).all() else 0.0
            if abs(m[i, 0] - m[j, 0]) < max(width, noise):
                out.append((i + 1, j + 1))
    return out
