"""Verified stream alignment from the closed-loop controller invariant (ROS-free).

With the known discrete controller ``C_d(q) = N(q^-1)/D(q^-1)`` aligned data satisfy ``D(q^-1) u(t_k) = N(q^-1) (r(t_k)
- y(t_k))`` ([RA-SRIVC] eq. 10), an FIR identity whose residual jumps from rounding level when one stream lost or
repeated a message. :class:`InvariantAligner` treats it as evidence: hypotheses are offsets ``(a, b)`` of ``u`` and
``r`` against ``y``; each has the Cauchy cost ``log(1 + (e_k/sigma_k)^2)`` (``sigma_k``: rounding level or the
residual's robust scale); a CUSUM per alternative, with a drift of ``drift`` nats per sample towards the current one,
switches at ``switch_nats`` and re-decides the samples since its last reset. Samples are released a fixed lag late, so a
shift is corrected before the estimator sees it; the samples around a re-alignment are released invalid, a missing
sample becomes an invalid grid sample, a surplus one is dropped. Undecided samples are counted, and the median relative
residual says whether the invariant holds to rounding (``verified``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple, TypedDict, Unpack

import numpy as np

from ..controller import DiscreteController
from ..estimation.compiled import kernel

_EPS = np.finfo(float).eps


@dataclass
class AlignmentStats:
    """Counters of one aligner (cumulative)."""

    samples_in: int = 0
    samples_out: int = 0
    realignments: int = 0                  # accepted changes of the offset hypothesis
    inserted: int = 0                      # grid samples added for a sample lost on y (y invalid there)
    missing: int = 0                       # grid samples with a lost u or r sample (invalid)
    surplus: int = 0                       # surplus (repeated or extra) samples of one stream dropped
    invalidated: int = 0                   # samples released invalid around uncertain re-alignments
    reconstructed: int = 0                 # lost samples recovered exactly from the invariant
    late: int = 0                          # samples already released before a change was detected (misaligned)
    undecided: int = 0                     # released samples where no alternative was separable
    residual_scale: float = math.nan       # running robust scale of the accepted residual
    relative_residual: float = math.nan    # median |e|/(rounding scale) over the last block
    offset: tuple[int, int] = (0, 0)       # current (u, r) index offset against y
    events: list[tuple[float, str]] = field(default_factory=list)   # (time, one-line message), drained by caller

    def to_dict(self) -> dict[str, object]:
        d = {k: v for k, v in self.__dict__.items() if k != "events"}
        d["offset"] = list(self.offset)
        return d


@dataclass
class AlignedBlock:
    """Samples released by the aligner: time, r (None in open loop), u, y; invalid samples are NaN."""

    t: np.ndarray
    r: np.ndarray | None
    u: np.ndarray
    y: np.ndarray
    invalid: np.ndarray     # bool: released invalid by the aligner (re-alignment window, lost or inserted sample)

    @property
    def n(self) -> int:
        return int(self.t.size)


class _Paired(NamedTuple):
    t: np.ndarray
    r: np.ndarray
    u: np.ndarray
    y: np.ndarray
    flagged: np.ndarray    # set aside by an uncertain re-alignment
    paired_out: np.ndarray  # a stream has no sample here because of the pairing (a lost message), not a NaN value
    inserted: int
    lost: int
    surplus: int


def invariant_residual(den: np.ndarray, num: np.ndarray, r: np.ndarray, u: np.ndarray,
                       y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Residual ``D(q^-1) u - N(q^-1)(r - y)`` ([RA-SRIVC] eq. 10) and the size of its terms from sample ``order``."""
    p = max(den.size, num.size) - 1
    d, nn = np.zeros(p + 1), np.zeros(p + 1)
    d[:den.size], nn[:num.size] = den, num
    e = _fir(d, u) - _fir(nn, r - y)
    scale = _fir(np.abs(d), np.abs(u)) + _fir(np.abs(nn), np.abs(r)) + _fir(np.abs(nn), np.abs(y))
    return e, scale


def reconstruct_missing(den: np.ndarray, num: np.ndarray, r: np.ndarray, u: np.ndarray, y: np.ndarray,
                        where: np.ndarray) -> int:
    """Fill samples missing on exactly one stream from the invariant (in place, at ``where``); returns how many.

    Only for samples that a lost message left empty: a NaN *value* is a sensor problem the controller saw too.

    ``u_k = N(q^-1)(r - y)_k - sum_{i>=1} d_i u_{k-i}`` and ``(r - y)_k = (D(q^-1) u_k - sum_{i>=1} n_i
    (r - y)_{k-i}) / n_0`` ([RA-SRIVC] eq. 10 with d_0 = 1), only where the other two streams and the whole window are
    finite, so that a reconstructed value is what the controller computed (use only on a verified invariant).
    """
    p = max(den.size, num.size) - 1
    d, nn = np.zeros(p + 1), np.zeros(p + 1)
    d[:den.size], nn[:num.size] = den, num
    miss = ~(np.isfinite(r) & np.isfinite(u) & np.isfinite(y)) & where
    done = 0
    for k in np.flatnonzero(miss):
        lack = (not np.isfinite(r[k]), not np.isfinite(u[k]), not np.isfinite(y[k]))
        if k < p or sum(lack) != 1:
            continue
        win = slice(k - p, k)
        if not (np.all(np.isfinite(r[win])) and np.all(np.isfinite(u[win])) and np.all(np.isfinite(y[win]))):
            continue
        e_past = (r[win] - y[win])[::-1]              # (r - y)_{k-1}, ..., (r - y)_{k-p}
        u_past = u[win][::-1]
        if lack[1]:
            u[k] = nn[0] * (r[k] - y[k]) + nn[1:] @ e_past - d[1:] @ u_past
        elif nn[0] != 0.0:
            e_k = (u[k] + d[1:] @ u_past - nn[1:] @ e_past) / nn[0]
            if lack[0]:
                r[k] = y[k] + e_k
            else:
                y[k] = r[k] - e_k
        else:
            continue
        done += 1
    return done


_EMPTY_BLOCK = AlignedBlock(np.empty(0), np.empty(0), np.empty(0), np.empty(0), np.empty(0, dtype=bool))


@dataclass(frozen=True)
class AlignmentSettings:
    """The ``alignment.*`` parameters (rows in ``config.py``): whether the stream aligner runs, and its options."""

    mode: str = "auto"           # auto | off
    max_shift: int = 3           # largest index offset of u or r against y searched (samples)
    lag_s: float = 0.008         # samples are released this late (s)
    switch_nats: float = 40.0    # evidence a different offset needs before the streams are re-aligned

    def aligner_options(self, rate_hz: float) -> AlignerOptions:
        """The :class:`InvariantAligner` keywords at ``rate_hz`` (the lag in samples, rounded up)."""
        return AlignerOptions(max_shift=self.max_shift, lag=int(math.ceil(self.lag_s * rate_hz)),
                              switch_nats=self.switch_nats)


class AlignerOptions(TypedDict, total=False):
    """The keyword options of :class:`InvariantAligner` (``alignment.*`` parameters and tuning)."""

    max_shift: int
    lag: int
    switch_nats: float
    drift: float
    scale_memory: int
    rounding: float


def _fir(coef: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``sum_i coef[i] x[k - i]`` for every ``k >= len(coef) - 1`` (valid part only)."""
    return np.convolve(x, coef, mode="valid")


class InvariantAligner:
    """Streaming re-pairing of ``r``, ``u``, ``y`` by the controller invariant (see the module docstring).

    ``push(t, r, u, y)`` takes samples paired by arrival order or stamps (equal lengths; ``t`` belongs to
    ``y``) and returns the samples it can release (lagged by ``lag`` samples); ``flush()`` releases the rest.
    Results do not depend on how the input is split into blocks.
    """

    CHUNK = 8192   # samples evaluated at once (bounds the (n, hypotheses) work arrays)

    def __init__(self, controller: DiscreteController, rate_hz: float, *, max_shift: int = 3, lag: int = 48,
                 switch_nats: float = 40.0, drift: float = 0.5, scale_memory: int = 4096,
                 rounding: float = 1e-12) -> None:
        if max_shift < 1:
            raise ValueError("max_shift must be >= 1")
        self.d = np.asarray(controller.den, dtype=float)
        self.nc = np.asarray(controller.num, dtype=float)
        self.order = max(self.d.size, self.nc.size) - 1
        self._dpad = np.zeros(self.order + 1)
        self._npad = np.zeros(self.order + 1)
        self._dpad[:self.d.size], self._npad[:self.nc.size] = self.d, self.nc
        self.h = 1.0 / float(rate_hz)
        self.M = int(max_shift)
        self.lag = max(int(lag), 2 * (self.order + 1) + self.M + 2)
        self.batch = max(1, self.lag // 2)
        self.switch = float(switch_nats)
        self.drift = float(drift)
        self.rounding = float(rounding)
        self.scale_alpha = 1.0 / max(int(scale_memory), 1)
        shifts = np.arange(-self.M, self.M + 1)
        self.hyp = np.array([(a, b) for a in shifts for b in shifts], dtype=np.int64)   # (S, 2) offset changes
        self._center = len(self.hyp) // 2                 # the hypothesis "no change" (0, 0)
        self.stats = AlignmentStats()
        # raw streams with absolute index of their first element
        self._data = np.empty((4, 4096))          # rows t, y, u, r (absolute index - _base), first _n valid
        self._marks = np.zeros((2, 4096), dtype=bool)   # rows: undecided, release invalid
        self._n = 0
        self._base = 0                    # absolute index of _y[0] (= of _u[0], _r[0] as received)
        self._cur = (0, 0)                # current hypothesis (a, b)
        self._pos = 0                     # absolute y index of the next sample to evaluate
        self._G = np.zeros(len(self.hyp))          # CUSUM statistics per hypothesis
        self._rho = np.zeros(len(self.hyp), dtype=np.int64)   # last reset index per hypothesis
        self._log_scale = math.nan        # running mean of log |e_best| (robust scale)
        self._log_rel = math.nan          # running mean of log(|e_best| / rounding scale)
        self._segments: list[tuple[int, int, int]] = [(0, 0, 0)]   # (first y index, a, b), increasing
        self._emit = 0                    # absolute y index of the next sample to release
        self._last_ui = -1                # last released u / r absolute index
        self._last_ri = -1
        self._last_t = math.nan
        # last released r, u, y (reconstruction window)
        self._hist: tuple[np.ndarray, ...] = (np.empty(0), np.empty(0), np.empty(0))

    # ------------------------------------------------------------------------------------------- input
    def push(self, t: np.ndarray, r: np.ndarray | None, u: np.ndarray, y: np.ndarray) -> AlignedBlock:
        """Add paired samples and return what can be released (see the class docstring)."""
        t = np.asarray(t, dtype=float)
        u = np.asarray(u, dtype=float)
        y = np.asarray(y, dtype=float)
        r = np.zeros_like(y) if r is None else np.asarray(r, dtype=float)
        self.stats.samples_in += y.size
        self._append(t, y, u, r)
        if self._base + self._y.size - self._pos < self.batch:
            return _EMPTY_BLOCK   # evaluate in batches: the per-call cost matters at 4 kHz in small blocks
        self._evaluate(final=False)
        return self._release(final=False)

    @property
    def _t(self) -> np.ndarray:
        return self._data[0, :self._n]

    @property
    def _y(self) -> np.ndarray:
        return self._data[1, :self._n]

    @property
    def _u(self) -> np.ndarray:
        return self._data[2, :self._n]

    @property
    def _r(self) -> np.ndarray:
        return self._data[3, :self._n]

    @property
    def _flag(self) -> np.ndarray:
        return self._marks[0, :self._n]

    @property
    def _invalid(self) -> np.ndarray:
        return self._marks[1, :self._n]

    def _append(self, t: np.ndarray, y: np.ndarray, u: np.ndarray, r: np.ndarray) -> None:
        m = t.size
        if self._n + m > self._data.shape[1]:
            cap = max(2 * self._data.shape[1], self._n + m)
            data, marks = np.empty((4, cap)), np.zeros((2, cap), dtype=bool)
            data[:, :self._n], marks[:, :self._n] = self._data[:, :self._n], self._marks[:, :self._n]
            self._data, self._marks = data, marks
        sl = slice(self._n, self._n + m)
        self._data[0, sl], self._data[1, sl], self._data[2, sl], self._data[3, sl] = t, y, u, r
        self._marks[:, sl] = False
        self._n += m

    def flush(self) -> AlignedBlock:
        """Release every remaining sample (end of a record)."""
        self._evaluate(final=True)
        return self._release(final=True)

    # ------------------------------------------------------------------------------------------- state
    _SCALARS = ("_base", "_pos", "_emit", "_last_ui", "_last_ri", "_last_t", "_log_scale", "_log_rel")

    def get_state(self) -> dict[str, object]:
        """Held-back samples and detector state as JSON-serializable data (continuation is bit-identical)."""
        return {"data": self._data[:, :self._n].tolist(), "marks": self._marks[:, :self._n].tolist(),
                **{k: getattr(self, k) for k in self._SCALARS},
                "cur": list(self._cur), "G": self._G.tolist(), "rho": self._rho.tolist(),
                "segments": [list(sg) for sg in self._segments], "hist": [h.tolist() for h in self._hist],
                "stats": {k: v for k, v in self.stats.to_dict().items()}}

    def set_state(self, state: dict) -> None:
        """Restore :meth:`get_state` output (same controller and ``max_shift``)."""
        data = np.asarray(state["data"], dtype=float).reshape(4, -1)
        self._n = data.shape[1]
        self._data = np.empty((4, max(4096, self._n)))
        self._marks = np.zeros((2, self._data.shape[1]), dtype=bool)
        self._data[:, :self._n] = data
        self._marks[:, :self._n] = np.asarray(state["marks"], dtype=bool).reshape(2, -1)
        for k in self._SCALARS:
            setattr(self, k, type(getattr(self, k))(state[k]))
        self._cur = (int(state["cur"][0]), int(state["cur"][1]))
        self._G = np.asarray(state["G"], dtype=float)
        self._rho = np.asarray(state["rho"], dtype=np.int64)
        if self._G.shape != (len(self.hyp),):
            raise ValueError("aligner state was saved with another alignment.max_shift")
        self._segments = [(int(a), int(b), int(c)) for a, b, c in state["segments"]]
        self._hist = tuple(np.asarray(h, dtype=float) for h in state["hist"])
        st = dict(state["stats"])
        st["offset"] = tuple(st["offset"])
        self.stats = AlignmentStats(**st)

    # ------------------------------------------------------------------------------------------- evidence
    def _evaluate(self, *, final: bool) -> None:
        """Advance the CUSUM change detection over every sample whose residuals are computable."""
        while True:
            a, b = self._cur
            stop = self._base + self._y.size - (0 if final else self.M + max(0, a, b))
            if self._pos >= stop:
                return
            k0 = self._pos
            end = min(stop, k0 + self.CHUNK)
            n = end - k0
            flags = np.zeros(n, dtype=np.bool_)
            state = np.array([self._log_scale, self._log_rel])
            i_det, w = _cusum_scan(self._data[2], self._data[3], self._data[1], self._n, k0 - self._base, n, a, b,
                                   self._dpad, self._npad, self.hyp, self._center, self._G, self._rho, k0,
                                   self.switch, self.drift, self.rounding, self.scale_alpha, state, flags)
            self._log_scale, self._log_rel = float(state[0]), float(state[1])
            if math.isfinite(self._log_scale):
                self.stats.residual_scale = math.exp(self._log_scale)
            if math.isfinite(self._log_rel):
                self.stats.relative_residual = math.exp(self._log_rel)
            done = n if i_det < 0 else i_det + 1
            j = k0 - self._base
            self._flag[j:j + done] = flags[:done]
            if i_det < 0:
                self._pos = end
                continue
            start = max(int(self._rho[w]), self._segments[-1][0] + 1)
            self._switch(start, (a + int(self.hyp[w, 0]), b + int(self.hyp[w, 1])))

    def _switch(self, start: int, new: tuple[int, int]) -> None:
        """Accept hypothesis ``new`` from (about) absolute y index ``start`` on and re-decide the samples after it.

        The CUSUM places a change up to ``order + 1`` samples late (the residuals right after a change are
        contaminated under both hypotheses); :meth:`_locate` finds the exact change point from the invariant of
        the re-paired streams. Only when that is not decisive are the samples around the change released invalid.
        """
        old = self._cur
        self.stats.realignments += 1
        dist = abs(new[0] - old[0]) + abs(new[1] - old[1])
        w = (self.order + 1) * max(1, dist)
        lo_c = max(start - 2 * w, self._emit, self._segments[-1][0] + 1)
        c, decisive = self._locate(lo_c, start, old, new)
        if c < self._emit:
            self.stats.late += self._emit - c
        c = max(c, self._emit)
        self._segments.append((c, new[0], new[1]))
        self._cur = new
        if not decisive:   # release the samples around the change invalid (two losses close together, no excitation)
            lo = max(c - w, self._emit) - self._base
            hi = min(c + w, self._base + self._y.size) - self._base
            if hi > lo:
                self._invalid[lo:hi] = True
        t = self._t[min(c - self._base, self._t.size - 1)]
        how = "" if decisive else f"; change point uncertain, {2 * w} samples set aside"
        self.stats.events.append((float(t), f"re-aligned the signals at t={t:.4f}: (u, r) offset against y "
                                  f"{old} -> {new} (controller invariant u = C_d(r - y){how})"))
        self.stats.offset = new
        # residuals whose window straddles the change mix both offsets: no evidence is taken from them (else the
        # old offset would look right again and the streams flip back and forth)
        self._pos = min(c + self.order + 1, self._base + self._y.size)
        self._G = np.zeros(len(self.hyp))
        self._rho = np.full(len(self.hyp), self._pos, dtype=np.int64)

    def _locate(self, lo_c: int, hi_c: int, old: tuple[int, int], new: tuple[int, int]) -> tuple[int, bool]:
        """Exact change point in ``[lo_c, hi_c]``: the one whose re-paired streams best satisfy the invariant.

        Returns ``(c, decisive)``; decisive when the best candidate beats every other by ``switch_nats / 4``.
        """
        if hi_c <= lo_c:
            return hi_c, False
        p = self.order
        k_lo = lo_c - p - 1
        k_hi = min(hi_c + 3 * (p + 1), self._base + self._y.size - self.M)
        if k_lo < self._base or k_hi <= hi_c:
            return hi_c, False
        ks = np.arange(k_lo, k_hi)
        sig = max(self.stats.residual_scale if math.isfinite(self.stats.residual_scale) else 0.0, 1e-300)
        costs, streams, worst = [], [], []
        for c in range(lo_c, hi_c + 1):
            a = np.where(ks < c, old[0], new[0])
            b = np.where(ks < c, old[1], new[1])
            pr = self._pair(ks, ks + a, ks + b, int(ks[0] + a[0] - 1), int(ks[0] + b[0] - 1), math.nan)
            if self.verified:   # as released: a sample lost on one stream is recovered, candidates compare whole
                reconstruct_missing(self.d, self.nc, pr.r, pr.u, pr.y, pr.paired_out)
            e, scale = invariant_residual(self.d, self.nc, pr.r, pr.u, pr.y)
            floor = np.maximum(self.rounding * scale, sig)
            cst = np.log1p((e / floor) ** 2)
            costs.append(float(np.sum(cst[np.isfinite(cst)])))
            worst.append(float(np.max(cst[np.isfinite(cst)], initial=0.0)))
            streams.append(np.concatenate((pr.r, pr.u, pr.y)))
        cost = np.asarray(costs)
        best = int(np.argmin(cost))
        # decisive: the best candidate explains every residual, and every candidate within the margin yields the
        # very same streams (e.g. a repeated message whose copies are equal, a constant reference)
        close = np.flatnonzero(cost - cost[best] <= self.switch / 4.0)
        explained = worst[best] <= self.switch / 4.0     # the best candidate fits every residual (one change only)
        decisive = explained and all(streams[i].shape == streams[best].shape
                       and np.array_equal(streams[i], streams[best], equal_nan=True) for i in close)
        return lo_c + best, bool(decisive)

    # ------------------------------------------------------------------------------------------- output
    def _pair(self, ks: np.ndarray, ui: np.ndarray, ri: np.ndarray, last_ui: int, last_ri: int,
              last_t: float) -> _Paired:
        """Grid samples for y indices ``ks`` read from ``u[ui]`` and ``r[ri]`` (absolute indices).

        A stream whose index does not advance lost a sample (NaN there); one that advances by two or more had a
        surplus sample (skipped); when u and r both advance by two or more, y lost a sample and a grid sample is
        inserted (y NaN); when neither advances, the y sample is a surplus (dropped).
        """
        j = ks - self._base
        prev_u = np.maximum.accumulate(np.concatenate(([last_ui], ui)))[:-1]
        prev_r = np.maximum.accumulate(np.concatenate(([last_ri], ri)))[:-1]
        du, dr = ui - prev_u, ri - prev_r
        started = (prev_u >= 0) | (prev_r >= 0)
        y_lost = started & (du >= 2) & (dr >= 2)
        n_ins = np.where(y_lost, np.minimum(du, dr) - 1, 0)
        y_surplus = started & (du <= 0) & (dr <= 0)
        u_lost = started & ~y_surplus & (du <= 0)
        r_lost = started & ~y_surplus & (dr <= 0)
        surplus = np.where(started & ~y_surplus, np.maximum(du - 1 - n_ins, 0) + np.maximum(dr - 1 - n_ins, 0), 0)
        n = self._u.size

        def take(x: np.ndarray, idx: np.ndarray, missing: np.ndarray) -> np.ndarray:
            rel = idx - self._base
            ok = (rel >= 0) & (rel < n) & ~missing
            return np.where(ok, x[np.clip(rel, 0, n - 1)], np.nan)

        uv, rv = take(self._u, ui, u_lost), take(self._r, ri, r_lost)
        yv, tv = self._y[j].copy(), self._t[j].copy()
        flagged = self._invalid[j].copy()
        out_of_data = ~((ui - self._base >= 0) & (ui - self._base < n) & (ri - self._base >= 0) & (ri - self._base < n))
        paired_out = u_lost | r_lost | out_of_data        # (out of data: the record's first or last samples)
        keep = ~y_surplus
        if n_ins.any():
            at = np.flatnonzero(n_ins)
            pos = np.repeat(at, n_ins[at])
            step = np.concatenate([np.arange(1, q + 1) for q in n_ins[at]])
            tprev = np.concatenate(([last_t], tv[:-1]))
            ins_u = take(self._u, prev_u[pos] + step, np.zeros(pos.size, dtype=bool))
            ins_r = take(self._r, prev_r[pos] + step, np.zeros(pos.size, dtype=bool))
            tv = np.insert(tv, pos, tprev[pos] + step * self.h)
            uv, rv = np.insert(uv, pos, ins_u), np.insert(rv, pos, ins_r)
            yv = np.insert(yv, pos, np.nan)
            flagged = np.insert(flagged, pos, False)
            paired_out = np.insert(paired_out, pos, True)
            keep = np.insert(keep, pos, True)
        return _Paired(tv[keep], rv[keep], uv[keep], yv[keep], flagged[keep], paired_out[keep], int(n_ins.sum()),
                       int(u_lost.sum() + r_lost.sum()), int(y_surplus.sum() + surplus.sum()))

    def _release(self, *, final: bool) -> AlignedBlock:
        """Release samples older than the lag on the accepted offsets (see the class docstring)."""
        n_have = self._base + self._y.size
        stop = min(self._pos if final else self._pos - self.lag, n_have)
        if stop <= self._emit:
            return _EMPTY_BLOCK
        fast = self._release_steady(stop)
        if fast is not None:
            return fast
        st = self.stats
        ks = np.arange(self._emit, stop)
        j = ks - self._base
        starts = np.array([sg[0] for sg in self._segments])
        seg = np.maximum(np.searchsorted(starts, ks, side="right") - 1, 0)
        ui = ks + np.array([sg[1] for sg in self._segments])[seg]
        ri = ks + np.array([sg[2] for sg in self._segments])[seg]
        pr = self._pair(ks, ui, ri, self._last_ui, self._last_ri, self._last_t)
        st.inserted += pr.inserted
        st.missing += pr.lost
        st.surplus += pr.surplus
        st.undecided += int(np.count_nonzero(self._flag[j]))
        r, u, y = pr.r, pr.u, pr.y
        r[pr.flagged] = u[pr.flagged] = y[pr.flagged] = np.nan
        st.invalidated += int(np.count_nonzero(pr.flagged))
        if self.verified:
            st.reconstructed += self._reconstruct(r, u, y, pr.paired_out & ~pr.flagged)
        self._hist = tuple(np.concatenate((hx, x))[-(self.order + 1):] for hx, x in zip(self._hist, (r, u, y),
                                                                                          strict=True))
        # the aligner's own invalid samples (a NaN value in the data stays the caller's to count and report)
        invalid = pr.flagged | (pr.paired_out & ~(np.isfinite(r) & np.isfinite(u) & np.isfinite(y)))
        self._last_ui = int(max(self._last_ui, ui.max()))
        self._last_ri = int(max(self._last_ri, ri.max()))
        self._last_t = float(self._t[j[-1]])
        self._emit = stop
        st.samples_out += pr.t.size
        self._trim()
        return AlignedBlock(pr.t, r, u, y, invalid)

    def _release_steady(self, stop: int) -> AlignedBlock | None:
        """The common case in O(1) numpy calls: one offset over the range, continuing the last release, nothing
        set aside; ``None`` otherwise (then :meth:`_pair` handles losses, surpluses and insertions)."""
        e0 = self._emit
        seg = self._segments[-1]
        if seg[0] > e0:
            return None
        a, b = seg[1], seg[2]
        j0, j1 = e0 - self._base, stop - self._base
        if (self._last_ui != e0 + a - 1 or self._last_ri != e0 + b - 1 or j0 + min(a, b) < 0
                or j1 + max(a, b) > self._n or self._invalid[j0:j1].any()):
            return None
        tv, yv = self._t[j0:j1].copy(), self._y[j0:j1].copy()
        uv, rv = self._u[j0 + a:j1 + a].copy(), self._r[j0 + b:j1 + b].copy()
        st = self.stats
        st.undecided += int(np.count_nonzero(self._flag[j0:j1]))
        keep = self.order + 1
        self._hist = tuple(np.concatenate((hx, x[-keep:]))[-keep:] for hx, x in zip(self._hist, (rv, uv, yv),
                                                                                   strict=True))
        self._last_ui, self._last_ri = stop - 1 + a, stop - 1 + b
        self._last_t = float(tv[-1])
        self._emit = stop
        st.samples_out += tv.size
        self._trim()
        return AlignedBlock(tv, rv, uv, yv, np.zeros(tv.size, dtype=bool))

    @property
    def verified(self) -> bool:
        """The invariant holds to rounding on the accepted pairing (a lost sample can be reconstructed exactly)."""
        rel = self.stats.relative_residual
        return math.isfinite(rel) and rel <= self.rounding

    def _reconstruct(self, r: np.ndarray, u: np.ndarray, y: np.ndarray, where: np.ndarray) -> int:
        """Fill samples a lost message left empty from the invariant, in place, after the released history."""
        hr, hu, hy = self._hist
        R, U, Y = (np.concatenate((h, x)) for h, x in ((hr, r), (hu, u), (hy, y)))
        done = reconstruct_missing(self.d, self.nc, R, U, Y, np.concatenate((np.zeros(hr.size, bool), where)))
        r[:], u[:], y[:] = R[hr.size:], U[hr.size:], Y[hr.size:]
        return done

    def _trim(self) -> None:
        """Forget samples no longer needed (released and outside every FIR window and offset in use)."""
        k = min(self._emit, self._pos)
        active = [sg for sg in self._segments if sg[0] <= k]
        live = [active[-1] if active else self._segments[0], *[sg for sg in self._segments if sg[0] > k]]
        low = min(0, *(sg[1] for sg in live), *(sg[2] for sg in live))
        cut = k + low - self.M - self.order - 2 - self._base
        if cut < 1024:
            return
        keep = self._n - cut
        self._data[:, :keep] = self._data[:, cut:self._n]
        self._marks[:, :keep] = self._marks[:, cut:self._n]
        self._n = keep
        self._base += cut
        act = [sg for sg in self._segments if sg[0] <= self._base][-1]
        self._segments = [(self._base, act[1], act[2])] + [sg for sg in self._segments if sg[0] > self._base]


@kernel
def _fir_terms(x, n_have, lo, hi, c):  # pragma: no cover - compiled
    """``sum_i c_i x[k - i]`` and ``sum_i |c_i x[k - i]|`` for buffer positions ``lo <= k < hi`` (NaN where the
    window leaves the data): each stream's part of the invariant, computed once per position, not per
    hypothesis."""
    p = c.size - 1
    m = max(hi - lo, 0)
    val = np.full(m, np.nan)
    mag = np.full(m, np.nan)
    for k in range(max(lo, p), min(hi, n_have)):
        v = 0.0
        a = 0.0
        for i in range(p + 1):
            t = c[i] * x[k - i]
            v += t
            a += abs(t)
        val[k - lo] = v
        mag[k - lo] = a
    return val, mag


@kernel
def _cusum_scan(u, r, y, n_have, j0, n, a0, b0, d, nc, hyp, cur, G, rho, k0, switch, drift, rounding, alpha,
                state, flags):  # pragma: no cover - compiled
    """Per-sample CUSUM of every offset hypothesis against the current one (module docstring).

    Buffer position ``j0 + i`` is y index ``k0 + i``; the current offsets ``(a0, b0)`` read u at ``j + a0`` and r
    at ``j + b0``, hypothesis ``s`` at ``j + a0 + hyp[s, 0]`` / ``j + b0 + hyp[s, 1]``. The residual
    ``D u - N (r - y)`` of a pairing is ``Du[ju] - Nr[jr] + Ny[j]`` with each stream's FIR part computed once
    (:func:`_fir_terms`). Updates ``G``, ``rho`` (last reset + 1) and ``state`` (running means of log |best
    residual| and of log(|best residual| / rounding scale)) in place; fills ``flags`` (undecided: an alternative
    with different data is not worse). Returns ``(i, s)`` at the first sample whose CUSUM of hypothesis ``s``
    exceeds ``switch``, else ``(-1, -1)``.
    """
    S = hyp.shape[0]
    lo_u = j0 + a0 + min(0, hyp[:, 0].min())
    lo_r = j0 + b0 + min(0, hyp[:, 1].min())
    du, au = _fir_terms(u, n_have, lo_u, j0 + n + a0 + max(0, hyp[:, 0].max()), d)
    nr, ar = _fir_terms(r, n_have, lo_r, j0 + n + b0 + max(0, hyp[:, 1].max()), nc)
    ny, ay = _fir_terms(y, n_have, j0, j0 + n, nc)
    log_scale = state[0]
    log_rel = state[1]
    for i in range(n):
        ju0 = i + a0 + (j0 - lo_u)
        jr0 = i + b0 + (j0 - lo_r)
        e_cur = du[ju0] - nr[jr0] + ny[i]
        if not np.isfinite(e_cur):
            continue
        scale = au[ju0] + ar[jr0] + ay[i]
        if not np.isfinite(scale):
            continue
        sig = max(rounding * scale, 1e-300)
        if np.isfinite(log_scale):
            sig = max(sig, np.exp(log_scale))
        c_cur = np.log1p((e_cur / sig) ** 2)
        best = abs(e_cur)
        e_sep = np.inf     # smallest |e| of the hypotheses whose data differ from the current pairing
        hit = -1
        g_hit = switch
        for s in range(S):
            if s == cur:
                continue
            e = du[ju0 + hyp[s, 0]] - nr[jr0 + hyp[s, 1]] + ny[i]
            if not np.isfinite(e):
                continue
            if abs(e) < best:
                best = abs(e)
            if abs(e - e_cur) > 1e-15 * scale and abs(e) < e_sep:
                e_sep = abs(e)
            dist = abs(hyp[s, 0]) + abs(hyp[s, 1])
            lead = G[s] + c_cur
            if lead - drift * (1.0 + dist) <= 0.0:
                # c = log1p(.) >= 0, so g = lead - c - drift (1 + dist) <= 0 as well (rounding is monotone): the
                # statistic restarts without its logarithm (most hypotheses at most samples)
                G[s] = 0.0
                rho[s] = k0 + i + 1
                continue
            c = np.log1p((e / sig) ** 2)
            g = lead - c - drift * (1.0 + dist)
            if g <= 0.0:
                G[s] = 0.0
                rho[s] = k0 + i + 1
            else:
                G[s] = g
                if g > g_hit:
                    g_hit = g
                    hit = s
        # separation: min over the differing hypotheses of c - c_cur, i.e. at their smallest |e| (c grows with |e|)
        sep = np.log1p((e_sep / sig) ** 2) - c_cur if e_sep < np.inf else np.inf
        flags[i] = sep <= drift
        if best > 0.0:
            lb = np.log(best)
            log_scale = lb if not np.isfinite(log_scale) else (1.0 - alpha) * log_scale + alpha * lb
            if scale > 0.0:
                lr = lb - np.log(scale)
                log_rel = lr if not np.isfinite(log_rel) else (1.0 - alpha) * log_rel + alpha * lr
        if hit >= 0:
            state[0] = log_scale
            state[1] = log_rel
            return i, hit
    state[0] = log_scale
    state[1] = log_rel
    return -1, -1


def align_record(controller: DiscreteController, rate_hz: float, t: np.ndarray, r: np.ndarray, u: np.ndarray,
                 y: np.ndarray, **options: Unpack[AlignerOptions]) -> tuple[AlignedBlock, AlignmentStats]:
    """A whole record through :class:`InvariantAligner` (offline tools: one push and a flush)."""
    al = InvariantAligner(controller, rate_hz, **options)
    a, b = al.push(t, r, u, y), al.flush()
    block = AlignedBlock(*(np.concatenate((getattr(a, k), getattr(b, k))) for k in ("t", "r", "u", "y", "invalid")))
    return block, al.stats
