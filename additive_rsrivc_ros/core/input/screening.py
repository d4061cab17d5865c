"""Screening of a whole record before a batch fit: which samples are garbage, which clean stretch is left.

The batch estimators filter on a uniform grid, so a fit needs contiguous, evenly spaced, valid samples. The rules mirror
the pipeline's sample validation, so the offline tools and the node call the same things bad: a repeated stamp is a
*duplicate*, an earlier one *out of order*; a *non-finite* value, or one of *absurd magnitude* (``|x| > ABSURD_ABS`` or
``|x - median|`` above ``ABSURD_REL`` robust scales); an output equal to the previous one is *held* (when
``faults.health.repeated_output_is_missing``); a spacing above ``(1 + faults.health.gap_tolerance) / rate`` is a *gap*.
:func:`screen` returns the counts per category and the longest clean segment; nothing is repaired.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

ABSURD_ABS = 1e12        # |x| above this is not a measurement
ABSURD_REL = 1e6         # nor is a value this many robust scales away from the record's median
MAD_TO_SIGMA = 1.4826    # robust scale of a Gaussian from its median absolute deviation


@dataclass
class Screening:
    """Result of :func:`screen`: per-category counts and the longest clean segment (indices into the input)."""

    n: int
    index: np.ndarray           # indices of the samples to use (the longest clean segment), increasing
    duplicates: int = 0
    out_of_order: int = 0
    nonfinite: dict[str, int] = field(default_factory=dict)
    absurd: dict[str, int] = field(default_factory=dict)
    held: int = 0
    gaps: int = 0
    pieces: int = 1

    @property
    def used(self) -> int:
        return int(self.index.size)

    def to_dict(self) -> dict:
        return {"samples": self.n, "samples_used": self.used, "duplicate_stamps": self.duplicates,
                "out_of_order_stamps": self.out_of_order, "nonfinite": dict(self.nonfinite),
                "absurd_magnitude": dict(self.absurd), "held_outputs": self.held, "data_gaps": self.gaps,
                "clean_segments": self.pieces}


def absurd_mask(x: np.ndarray, abs_limit: float = ABSURD_ABS, rel_limit: float = ABSURD_REL) -> np.ndarray:
    """Finite values whose magnitude no real signal of this record has (see the module docstring)."""
    x = np.asarray(x, float)
    fin = np.isfinite(x)
    out = np.zeros(x.shape, bool)
    if not fin.any():
        return out
    xf = x[fin]
    med = float(np.median(xf))
    dev = np.abs(xf - med)
    scale = MAD_TO_SIGMA * float(np.median(dev))
    if not scale > 0:
        scale = float(np.mean(dev[dev < np.percentile(dev, 99)])) if dev.size > 1 else 0.0
    bad = np.abs(xf) > abs_limit
    if scale > 0 and np.isfinite(scale):
        bad |= dev > rel_limit * scale
    out[fin] = bad
    return out


def screen(t: np.ndarray, signals: dict[str, np.ndarray | None], rate_hz: float, gap_tolerance: float, *,
           held_is_missing: bool = True) -> Screening:
    """Classify the samples of a record (times ``t`` in s, ``signals`` name -> values, ``output`` required).

    Returns the counts per category and the longest run of samples that are valid and spaced by at most
    ``(1 + gap_tolerance) / rate_hz`` (dropped stamps are skipped, the spacing is measured between kept samples).
    """
    t = np.asarray(t, float)
    n = t.size
    prev = np.maximum.accumulate(np.concatenate(([-np.inf], t[:-1]))) if n else t
    dup = t == prev
    ooo = t < prev
    keep = ~(dup | ooo)
    bad = np.zeros(n, bool)
    res = Screening(n=n, index=np.zeros(0, np.int64), duplicates=int(dup.sum()), out_of_order=int(ooo.sum()))
    for name, x in signals.items():
        if x is None:
            continue
        x = np.asarray(x, float)
        nf, ab = ~np.isfinite(x) & keep, absurd_mask(x) & keep
        if nf.any():
            res.nonfinite[name] = int(nf.sum())
        if ab.any():
            res.absurd[name] = int(ab.sum())
        bad |= nf | ab
    idx = np.flatnonzero(keep)
    y = np.asarray(signals["output"], float)[idx]
    held = np.zeros(idx.size, bool)
    if held_is_missing and idx.size > 1:
        held[1:] = (y[1:] == y[:-1]) & np.isfinite(y[1:]) & ~bad[idx[1:]]
    res.held = int(held.sum())
    ok = ~bad[idx] & ~held
    # break points: a bad sample, or a gap before a kept sample
    gap = np.zeros(idx.size, bool)
    if idx.size > 1:
        gap[1:] = np.diff(t[idx]) > (1.0 + gap_tolerance) / rate_hz
    res.gaps = int(gap.sum())
    first = ok & (np.concatenate(([True], ~ok[:-1])) | gap)     # a clean run starts here
    label = np.cumsum(first)
    res.pieces = int(first.sum())
    if res.pieces:
        lengths = np.bincount(label[ok], minlength=res.pieces + 1)
        res.index = idx[ok & (label == int(np.argmax(lengths)))]
    return res
