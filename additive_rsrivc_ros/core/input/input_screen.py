"""Screening of the samples the monitor pipeline receives, before the estimator sees any of them.

Step 1, stamps: non-finite, duplicate and out-of-order stamps are dropped, a recorder clock that stepped back is
re-based onto the grid, and the stamps' own spacing is checked against ``loop_rate_hz``. Step 2, values:
non-finite and absurd samples (:class:`MagnitudeGuard`) stay on the grid as invalid samples, the missing samples of
short gaps are filled in as invalid. Steps 3-4: gaps and runs of repeated outputs (a stuck sensor) are marked for
the pipeline, which re-primes the filters there ([RA-SRIVC] Algorithm 2 step 1). Garbage never reaches the
estimator as data. Each finding is a health note and a count (:class:`.report_record.Counters`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..diagnosis.faults import FaultSettings, HealthMonitor
from ..monitor.report_record import Counters
from .time_scale import StampSpacing

ABSOLUTE_BOUND = 1e15
"""|value| above which a sample is never data (about 1e9 x any physical signal in SI units)."""
RELATIVE_BOUND = 1e6
"""|value| above this x the running scale (the 99th percentile of the nonzero |value| seen so far) is not data."""
SCALE_QUANTILE = 0.99
"""Quantile of |value| used as the running scale: robust to 1 % outliers, and a signal that idles near its noise
floor for most of the record and then moves (a setpoint starting late) still sets its scale from the motion."""
MAGNITUDE_MIN_SAMPLES = 32    # nonzero samples seen before the relative bound applies
CLOCK_STEP_SPACING_TOL = 0.1  # a stamp before its predecessor, then a spacing this regular: a clock step
_LOG_BINS_PER_DECADE = 4
_LOG_MIN, _LOG_MAX = -330.0, 310.0


class MagnitudeGuard:
    """Running robust scale of a signal: a histogram of ``log10 |x|`` over every accepted nonzero sample.

    A finite sample is *absurd* when ``|x| > ABSOLUTE_BOUND`` or, once ``MAGNITUDE_MIN_SAMPLES`` nonzero samples were
    seen, ``|x| > RELATIVE_BOUND x`` the ``SCALE_QUANTILE`` quantile of ``|x|`` (to a quarter decade; isolated
    outliers cannot move it).
    """

    def __init__(self) -> None:
        self.hist = np.zeros(int((_LOG_MAX - _LOG_MIN) * _LOG_BINS_PER_DECADE) + 1, dtype=np.int64)
        self.n = 0
        self._scale = math.nan
        self._n_at_median = 0

    def bound(self) -> float:
        """Current magnitude bound (``ABSOLUTE_BOUND`` until enough samples were seen)."""
        if self.n < MAGNITUDE_MIN_SAMPLES:
            return ABSOLUTE_BOUND
        if self.n >= 2 * self._n_at_median or self.n - self._n_at_median >= 4096 or math.isnan(self._scale):
            k = int(np.searchsorted(np.cumsum(self.hist), math.ceil(SCALE_QUANTILE * self.n)))
            self._scale = 10.0 ** (_LOG_MIN + (k + 0.5) / _LOG_BINS_PER_DECADE)
            self._n_at_median = self.n
        return min(ABSOLUTE_BOUND, RELATIVE_BOUND * self._scale)

    def absurd(self, x: np.ndarray) -> np.ndarray:
        """Bool mask of finite samples above the bound (non-finite ones are not flagged here)."""
        return np.isfinite(x) & (np.abs(x) > self.bound())

    def learn(self, x: np.ndarray) -> None:
        """Add accepted samples (finite, not absurd) to the scale."""
        a = np.abs(x[np.isfinite(x)])
        a = a[a > 0.0]
        if a.size:
            k = np.clip(((np.log10(a) - _LOG_MIN) * _LOG_BINS_PER_DECADE).astype(np.int64), 0, self.hist.size - 1)
            self.hist += np.bincount(k, minlength=self.hist.size)
            self.n += int(a.size)

    def get_state(self) -> dict[str, Any]:
        nz = np.flatnonzero(self.hist)
        return {"bins": nz.tolist(), "counts": self.hist[nz].tolist()}

    def set_state(self, d: Mapping[str, Any]) -> None:
        self.hist[:] = 0
        self.hist[np.asarray(d["bins"], dtype=np.int64)] = np.asarray(d["counts"], dtype=np.int64)
        self.n = int(self.hist.sum())
        self._scale, self._n_at_median = math.nan, 0


@dataclass
class Screened:
    """Stamp-checked samples after the value checks: the grid (short gaps filled), what is valid data, and where
    the grid breaks (``gap``) or the output is stuck (``stuck``); ``prev_t`` is each sample's predecessor time."""

    t: np.ndarray
    r: np.ndarray
    u: np.ndarray
    y: np.ndarray
    valid: np.ndarray
    repeated: np.ndarray
    gap: np.ndarray
    prev_t: np.ndarray
    stuck: np.ndarray
    run_t0: np.ndarray

    def blocks(self, stuck_before: bool) -> list[tuple[int, int]]:
        """``[a, b)`` index ranges between gaps and stuck transitions (``stuck_before``: stuck at the last one)."""
        n = self.t.size
        st = self.stuck
        cuts = np.flatnonzero(self.gap | np.concatenate(([st[0] != stuck_before], st[1:] != st[:-1])))
        bounds = [0, *[int(j) for j in cuts if j > 0], n]
        return list(zip(bounds[:-1], bounds[1:], strict=True))


class InputScreen:
    """The pipeline's screening state: time origin, last stamps, clock offset, the magnitude guards and the run
    of repeated outputs; see the module docstring. Notes go to the health monitor passed to each call (the
    pipeline replaces it when the modes change)."""

    def __init__(self, rate_hz: float, counters: Counters) -> None:
        self.rate = float(rate_hz)
        self.h = 1.0 / self.rate
        self.counters = counters
        self.t0: float | None = None          # absolute time of the first sample
        self.t_last: float | None = None      # absolute time of the last accepted sample
        self.t_stamp_last: float | None = None  # last stamp accepted by step 1 (the aligner may hold samples back)
        self.clock_offset = 0.0                 # added to every stamp since a recorder clock stepped back (s)
        self.spacing = StampSpacing(self.rate)  # loop_rate_hz against the stamps' own spacing
        self.magnitude = {name: MagnitudeGuard() for name in ("reference", "input", "output")}
        self.stuck = False
        self.last_y: float | None = None
        self.run_len = 0                      # identical consecutive finite outputs so far
        self.run_start_t = math.nan           # absolute time the current run of identical outputs began

    def rel(self, t_abs: float) -> float:
        """Seconds since the first sample (0 before it)."""
        return float(t_abs - self.t0) if self.t0 is not None else 0.0

    # ------------------------------------------------------------------------------------------- step 1: stamps
    def accept_stamps(self, t: np.ndarray, r: np.ndarray, u: np.ndarray, y: np.ndarray,
                      health: HealthMonitor) -> tuple[np.ndarray, ...]:
        """Step 1: drop samples with non-finite, duplicate and out-of-order stamps (they never touch the grid)."""
        c = self.counters
        finite_t = np.isfinite(t)
        if self.t0 is None:
            if not finite_t.any():
                c.samples_dropped += t.size
                return t[:0], r[:0], u[:0], y[:0]
            self.t0 = float(t[np.argmax(finite_t)])
        t = self._rebase_clock_steps(t, health)
        start = -np.inf if self.t_stamp_last is None else self.t_stamp_last
        prev = np.maximum.accumulate(np.concatenate(([start], np.where(finite_t, t, -np.inf))))[:-1]
        ok_t = finite_t & (t > prev)
        if not ok_t.all():
            dup = finite_t & (t == prev)
            n_dup, n_bad = int(dup.sum()), int((~ok_t).sum())
            c.duplicates += n_dup
            c.out_of_order += n_bad - n_dup
            c.samples_dropped += n_bad
            t_note = self.rel(float(np.max(prev[~ok_t]))) if np.isfinite(prev[~ok_t]).any() else 0.0
            if n_dup:
                health.note("duplicate_stamps", t_note, f"{c.duplicates} duplicate time stamps dropped")
            if n_bad > n_dup:
                health.note("out_of_order", t_note, f"{c.out_of_order} out-of-order or invalid time stamps dropped")
        idx = np.flatnonzero(ok_t)
        if idx.size:
            self.t_stamp_last = float(t[idx[-1]])
            self.spacing.add(t[idx])
            if self.spacing.error:
                health.note("time_scale", self.rel(float(t[idx[-1]])), self.spacing.error)
        return t[idx], r[idx], u[idx], y[idx]

    def _rebase_clock_steps(self, t: np.ndarray, health: HealthMonitor) -> np.ndarray:
        """A recorder clock stepped back: from a sample on, every stamp is earlier by the same amount while the
        spacing stays the loop's. Those samples are not out of order; their stamps are re-based onto the grid (the
        offset is kept for later batches) and the step is reported, so no data is dropped or shifted."""
        t = t + self.clock_offset if self.clock_offset else t.copy()
        h = self.h
        last = -np.inf if self.t_stamp_last is None else self.t_stamp_last
        with np.errstate(invalid="ignore"):
            back = np.flatnonzero(np.diff(np.concatenate(([last], t))) < 0.0)    # candidates only: a cheap scan
        for j in back:
            prev = last if j == 0 else float(t[j - 1])
            if not (math.isfinite(t[j]) and math.isfinite(prev)) or t[j] >= prev:
                continue
            regular = j + 1 < t.size and abs((t[j + 1] - t[j]) - h) <= CLOCK_STEP_SPACING_TOL * h
            if not regular:
                continue            # a lone out-of-order stamp: dropped by the caller
            step = prev + h - float(t[j])
            t[j:] += step
            self.clock_offset += step
            self.counters.clock_steps += 1
            health.note("clock_step", self.rel(prev), f"time stamps stepped back by {1e3 * step:.4g} ms at "
                        f"t={self.rel(prev):.3f} s: re-based onto the sample grid (no sample dropped)")
        return t

    # ------------------------------------------------------------------------------------------- steps 2-4
    def screen(self, ta: np.ndarray, ra: np.ndarray, ua: np.ndarray, ya: np.ndarray, *,
               aligner_invalid: np.ndarray | None, settings: FaultSettings, closed_loop: bool,
               fill_max: Callable[[], int], health: HealthMonitor) -> Screened:
        """Values (non-finite, absurd, filled short gaps), gaps and repeated or stuck outputs of stamp-checked
        samples; ``fill_max()``: the longest gap filled instead of a re-prime (asked only when a gap is short)."""
        c = self.counters
        s = settings
        ta, ra, ua, ya, filled = self._fill_short_gaps(ta, ra, ua, ya, s.health_gap_tolerance, fill_max)
        if aligner_invalid is not None and filled.any():
            grown = np.zeros(filled.size, dtype=bool)
            grown[~filled] = aligner_invalid
            aligner_invalid = grown
        fin, absurd = self._valid_values(ta, ra, ua, ya, filled, closed_loop, health)
        # 3. gaps: spacing above (1 + tol) h between accepted samples
        prev_t = np.concatenate(([self.t_last if self.t_last is not None else ta[0]], ta[:-1]))
        gap = (ta - prev_t) > (1.0 + s.health_gap_tolerance) * self.h
        # 4. repeated outputs and stuck runs (on the finite samples)
        rep, run_len, run_t0 = self._runs(ta, ya, fin)
        stuck_n = max(s.health_stuck_min_samples, int(math.ceil(s.health_stuck_s * self.rate)))
        stuck = run_len >= stuck_n
        # carry stuck status through non-finite samples inside a stuck run
        if not fin.all():
            st_f = np.where(fin, stuck.astype(float), np.nan)
            st_f = _ffill(st_f, 1.0 if self.stuck else 0.0)
            stuck = st_f > 0.5
        valid = fin & ~(rep & s.health_repeated_output_is_missing)
        nonfin = ~fin & ~filled & ~absurd
        if aligner_invalid is not None:   # set aside by the aligner (re-alignment, lost sample): not sensor NaNs
            nonfin &= ~aligner_invalid
        n_nonfin = int(nonfin.sum())
        if n_nonfin:
            c.nonfinite += n_nonfin
            health.note("nonfinite", self.rel(float(ta[np.flatnonzero(nonfin)[-1]])),
                        f"{c.nonfinite} non-finite sensor samples skipped")
        n_fill = int(filled.sum())
        if n_fill:
            c.filled += n_fill
            health.note("data_gap", self.rel(float(ta[np.flatnonzero(filled)[-1]])),
                        f"{c.filled} missing samples of short gaps filled as invalid samples (grid kept)")
        return Screened(ta, ra, ua, ya, valid, rep, gap, prev_t, stuck, run_t0)

    def _runs(self, ta: np.ndarray, ya: np.ndarray, fin: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per sample: repeats its predecessor's output, length of the run of identical outputs it ends, and the
        run's start time (over the finite samples; the run continues from the last batch)."""
        n = ta.size
        fi = np.flatnonzero(fin)
        rep = np.zeros(n, dtype=bool)
        run_len = np.zeros(n, dtype=np.int64)
        run_t0 = np.full(n, np.nan)
        if fi.size:
            yf = ya[fi]
            prev_y = np.concatenate(([np.nan if self.last_y is None else self.last_y], yf[:-1]))
            eq = yf == prev_y
            k = np.arange(fi.size)
            last_reset = np.maximum.accumulate(np.where(~eq, k, -1))
            rl = np.where(last_reset >= 0, k - last_reset + 1, self.run_len + k + 1)
            rt = np.where(last_reset >= 0, ta[fi[np.maximum(last_reset, 0)]], self.run_start_t)
            rep[fi], run_len[fi], run_t0[fi] = eq, rl, rt
            self.last_y, self.run_len, self.run_start_t = float(yf[-1]), int(rl[-1]), float(rt[-1])
        return rep, run_len, run_t0

    def _fill_short_gaps(self, ta: np.ndarray, ra: np.ndarray, ua: np.ndarray, ya: np.ndarray, gap_tolerance: float,
                         fill_max: Callable[[], int],
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Insert the missing grid samples of short gaps (at most ``fill_max()``) as NaN samples."""
        filled = np.zeros(ta.size, dtype=bool)
        if self.t_last is None and ta.size < 2:
            return ta, ra, ua, ya, filled
        prev_t = np.concatenate(([self.t_last if self.t_last is not None else ta[0]], ta[:-1]))
        dt = ta - prev_t
        missing = np.rint(dt / self.h).astype(np.int64) - 1
        short = (dt > (1.0 + gap_tolerance) * self.h) & (missing >= 1)
        if not short.any():
            return ta, ra, ua, ya, filled
        short &= missing <= fill_max()
        if not short.any():
            return ta, ra, ua, ya, filled
        reps = np.where(short, missing + 1, 1)
        pos = np.repeat(np.arange(ta.size), reps)                     # source sample of every output row
        k_in = np.arange(pos.size) - np.repeat(np.cumsum(reps) - reps, reps)   # 0..reps-1 within a group
        is_fill = k_in < reps[pos] - 1
        frac = (k_in + 1) / reps[pos]
        t_out = np.where(is_fill, prev_t[pos] + frac * dt[pos], ta[pos])
        nan = np.full(pos.size, np.nan)
        return (t_out, np.where(is_fill, nan, ra[pos]), np.where(is_fill, nan, ua[pos]),
                np.where(is_fill, nan, ya[pos]), is_fill)

    def _valid_values(self, ta: np.ndarray, ra: np.ndarray, ua: np.ndarray, ya: np.ndarray, filled: np.ndarray,
                      closed_loop: bool, health: HealthMonitor) -> tuple[np.ndarray, np.ndarray]:
        """(valid, absurd): finite samples of plausible magnitude (:class:`MagnitudeGuard`), and the finite ones of
        absurd magnitude (counted as outliers and noted on health). An absurd value is set to NaN in place: it is
        never data (the estimator holds that signal at its last value, the initialization skips the sample)."""
        sigs = [("input", ua), ("output", ya)] + ([("reference", ra)] if closed_loop else [])
        fin = np.ones(ta.size, dtype=bool)
        absurd = np.zeros(ta.size, dtype=bool)
        bad_of = {}
        worst = ""
        for name, x in sigs:
            fin &= np.isfinite(x)
            bad = bad_of[name] = self.magnitude[name].absurd(x)
            if bad.any():
                j = int(np.argmax(np.where(bad, np.abs(x), -1.0)))
                worst = (f"|{name}| = {abs(float(x[j])):.3g} > {self.magnitude[name].bound():.3g} at "
                         f"t={self.rel(float(ta[j])):.3f} s")
            absurd |= bad
        ok = fin & ~absurd & ~filled
        for name, x in sigs:
            self.magnitude[name].learn(x[ok])
            x[bad_of[name]] = np.nan
        n_out = int(absurd.sum())
        if n_out:
            self.counters.outliers += n_out
            health.note("outlier", self.rel(float(ta[np.flatnonzero(absurd)[-1]])),
                        f"{self.counters.outliers} samples of absurd magnitude skipped as invalid "
                        f"(latest {worst}; bound {RELATIVE_BOUND:g} x the 99th percentile of |value| so far, "
                        f"at most {ABSOLUTE_BOUND:g})")
        return fin & ~absurd, absurd

    # ------------------------------------------------------------------------------------------- state
    def get_state(self) -> dict[str, Any]:
        """The screening part of the pipeline's saved state (keys as in :meth:`.pipeline.MonitorPipeline.get_state`)."""
        return {"t0": self.t0, "t_last": self.t_last, "stuck": self.stuck, "last_y": self.last_y,
                "run_len": self.run_len, "run_start_t": self.run_start_t, "t_stamp_last": self.t_stamp_last,
                "clock_offset": self.clock_offset, "magnitude": {k: g.get_state() for k, g in self.magnitude.items()}}

    def set_state(self, p: Mapping[str, Any]) -> None:
        """Restore :meth:`get_state` keys (states saved before ``t_stamp_last``/``clock_offset`` existed load)."""
        self.t0 = None if p["t0"] is None else float(p["t0"])
        self.t_last = None if p["t_last"] is None else float(p["t_last"])
        self.stuck = bool(p["stuck"])
        self.last_y = None if p["last_y"] is None else float(p["last_y"])
        self.run_len, self.run_start_t = int(p["run_len"]), float(p["run_start_t"])
        ts = p.get("t_stamp_last", p["t_last"])
        self.t_stamp_last = None if ts is None else float(ts)
        self.clock_offset = float(p.get("clock_offset", 0.0))
        for k, g in (p.get("magnitude") or {}).items():
            if k in self.magnitude:
                self.magnitude[k].set_state(g)


def _ffill(x: np.ndarray, first: float) -> np.ndarray:
    """Forward-fill NaNs (``first`` before the first finite value)."""
    idx = np.where(np.isnan(x), -1, np.arange(x.size))
    idx = np.maximum.accumulate(idx)
    out = np.where(idx >= 0, x[np.maximum(idx, 0)], first)
    return out
