"""Restart after a data break with the plant's free response fitted instead of waited out.

After a break the filters restart from rest ([RA-SRIVC] Algorithm 2 step 1), so each mode's simulated output
``x_i = b0_i / A_i(p) u`` misses the plant's free response from its unknown state at the restart. With the filter
model equal to the model, the equation error of mode ``i`` (eqs. 26-27) is exactly the output error ``y - sum_j x_j``
whatever the output filters' start (the filter's own differential equation), so that free response is the only
transient, and it decays with the slowest mode: the default re-prime hold waits five of its time constants.

:class:`FreeResponseRestart` instead collects the first few periods after the break (no updates), fits the
states of the input filters (bank ``U``, two per mode) by least squares to the output error, adds the fitted free
response to those filters and lets the updates resume. It is the recursive twin of the offline fit of a window cut
from a running plant (``identify(in_motion=True)``). It only shortens the hold: with a rigid body, modes too close
to separate in the collection window, or a fit that is not well posed, the full hold runs as before.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
from scipy.signal import lfilter

from . import kernel as kn

SETTLE_PERIODS = 3.0
"""Periods of the slowest mode collected before the fit."""
SETTLE_BEATS = 2.0
"""... and at least this many beat periods ``1 / |f_i - f_j|`` of the closest pair of modes."""
MAX_CONDITION = 1e6
"""Largest condition number of the (column-scaled) free-response basis accepted for the fit."""
MIN_EXPLAINED = 0.9
"""Fraction of the collected output error the fitted free response must explain, unless what it leaves is within
twice the residual level before the break; below it (a plant that changed during the break: the mismatch would
corrupt the fitted states) the collection is doubled, up to the full hold."""
APPLIED, EXTEND, FAILED = "applied", "extend", "failed"
STATE_KEY = "free_response_restart"
"""Key of a collection in progress in the estimator's snapshot (empty when none is)."""
_HEADER = 5   # n_target, residual accumulator, its weight, last finite input before the break, misfit seen


def settle_length(theta: np.ndarray, kind: np.ndarray, rate_hz: float, delay: int) -> int:
    """Samples to collect after a break: :data:`SETTLE_PERIODS` of the slowest mode, :data:`SETTLE_BEATS` of the
    closest pair, plus the input delay; 0 when the fit does not apply (a rigid body or a mode that is not a
    resonance)."""
    if np.any(kind != 0):
        return 0
    f = []
    for i in range(kind.size):
        a1, a2 = float(theta[i, 0]), float(theta[i, 1])
        if not (a1 > 0.0 and a2 > 0.0) or a1 * a1 >= 4.0 * a2:      # overdamped or unstable: no period
            return 0
        f.append(math.sqrt(1.0 / a2 - (a1 / (2.0 * a2)) ** 2) / (2.0 * math.pi))
    fs = np.sort(np.asarray(f))
    seconds = SETTLE_PERIODS / fs[0]
    if fs.size > 1:
        gap = float(np.min(np.diff(fs)))
        seconds = max(seconds, SETTLE_BEATS / gap) if gap > 0.0 else math.inf
    if not math.isfinite(seconds):
        return 0
    return int(math.ceil(seconds * rate_hz)) + delay + 1


class FreeResponseRestart:
    """One collection after a break: :meth:`add` the samples, then :meth:`apply` the fit to the kernel state."""

    def __init__(self, n_target: int, sig_acc: float, sig_w: float, u_last: float,
                 samples: np.ndarray | None = None, misfit: bool = False) -> None:
        self.n_target = int(n_target)
        self.sig_acc, self.sig_w, self.u_last = float(sig_acc), float(sig_w), float(u_last)
        self.misfit = bool(misfit)      # a fit left more than the noise: the plant changed during the break
        self._buf = np.zeros((4, self.n_target))           # r, u, y, valid of the samples collected so far
        self._n = 0
        if samples is not None:
            self.add(*np.asarray(samples, dtype=float).reshape(4, -1))

    @property
    def samples(self) -> np.ndarray:
        return self._buf[:, :self._n]

    @classmethod
    def begin(cls, s: Mapping[str, np.ndarray], rate_hz: float) -> FreeResponseRestart | None:
        """A collection for the state just reset after a break, or None when the full hold is shorter or needed."""
        n = settle_length(s["thf"], s["kind"], rate_hz, int(s["cfg_i"][kn.C_DELAY]))
        if n <= 0 or n >= int(s["ist"][kn.I_HOLD]) or not np.all(np.isfinite(s["phi"])):
            return None
        fst = s["fst"]
        return cls(n, fst[kn.F_SIGACC], fst[kn.F_SIGW], fst[kn.F_ULAST])

    @property
    def missing(self) -> int:
        return self.n_target - self._n

    def add(self, r: np.ndarray, u: np.ndarray, y: np.ndarray, valid: np.ndarray) -> None:
        """Collect samples (at most :attr:`missing`: the caller splits its block there)."""
        k = min(np.size(u), self.missing)
        for row, v in enumerate((r, u, y, valid)):
            self._buf[row, self._n:self._n + k] = np.asarray(v, dtype=float)[:k]
        self._n += k

    def keep_residual_level(self, s: dict[str, np.ndarray]) -> None:
        """The residual-variance accumulator as it was at the break (the collected output error is mostly the free
        response being fitted, not noise), until a fit finds more than the noise left: then the output error since
        the break is an anomaly (the plant changed during it) and health sees it from then on, as without a fit."""
        if not self.misfit:
            s["fst"][kn.F_SIGACC], s["fst"][kn.F_SIGW] = self.sig_acc, self.sig_w

    def apply(self, s: dict[str, np.ndarray]) -> str:
        """Fit the input filters' states at the break and add their free response to the kernel state; end the
        hold (:data:`APPLIED`). :data:`EXTEND`: the fitted response leaves more than the noise and explains less
        than :data:`MIN_EXPLAINED` of the output error (the plant changed during the break): collect twice as long.
        :data:`FAILED` (the hold runs on): the fit is not well posed, does not reproduce the kernel's filters, or
        the hold ends first."""
        _, u, y, valid = self.samples
        K = int(s["cfg_i"][kn.C_K])
        d = int(s["cfg_i"][kn.C_DELAY])
        n = u.size
        held = _held_input(u, self.u_last)
        w = np.concatenate((np.zeros(d + 1), held))[:n]        # the U bank's input: the input d + 1 samples back
        ysim = np.zeros(n)
        basis = np.zeros((n, 2 * K))
        ends = np.zeros((K, 2, 2))                              # Phi^n of each mode
        for i in range(K):
            phi, gam, b0 = s["phi"][i], s["gam"][i], float(s["thf"][i, 2])
            x0 = lfilter([gam[0], phi[0, 1] * gam[1] - phi[1, 1] * gam[0]],
                         [1.0, -np.trace(phi), np.linalg.det(phi)], w)
            if not np.allclose(x0[-1], s["xs"][i, kn.BU, 0], rtol=1e-7, atol=1e-12 * (1.0 + np.abs(x0).max())):
                return FAILED                                  # the filters moved during the collection
            ysim += b0 * x0
            basis[:, 2 * i:2 * i + 2] = b0 * _first_row_powers(phi, n)
            ends[i] = np.linalg.matrix_power(phi, n)
        ok = (valid != 0) & np.isfinite(y) & np.isfinite(u)
        ok[:d] = False      # the inputs still in the delay line at the break reach them: not a free response
        scale = np.sqrt(np.sum(basis[ok] ** 2, axis=0))
        if ok.sum() < 4 * K or not np.all(scale > 0.0):
            return FAILED
        a = basis[ok] / scale
        if np.linalg.cond(a) > MAX_CONDITION:
            return FAILED
        e = (y - ysim)[ok]
        c = np.linalg.lstsq(a, e, rcond=None)[0] / scale
        rest = float(np.mean((e - basis[ok] @ c) ** 2))
        noise = self.sig_acc / self.sig_w if self.sig_w > 0.0 else math.inf
        if rest > (1.0 - MIN_EXPLAINED) * float(np.mean(e ** 2)) and rest > 2.0 * noise:
            self.misfit = True
            return EXTEND if self._extend(s) else FAILED
        for i in range(K):
            s["xs"][i, kn.BU] += ends[i] @ c[2 * i:2 * i + 2]
        s["ist"][kn.I_HOLD] = 0
        return APPLIED

    def _extend(self, s: Mapping[str, np.ndarray]) -> bool:
        """Collect twice as many samples, if the hold lasts that long."""
        target = 2 * self.n_target
        if target - self._n > int(s["ist"][kn.I_HOLD]):
            return False
        self._buf = np.hstack((self._buf, np.zeros((4, target - self.n_target))))
        self.n_target = target
        return True

    def to_array(self) -> np.ndarray:
        head = np.array([self.n_target, self.sig_acc, self.sig_w, self.u_last, float(self.misfit)])
        return np.concatenate((head, self.samples.ravel()))

    @classmethod
    def from_array(cls, a: np.ndarray) -> FreeResponseRestart | None:
        """The collection saved by :meth:`to_array` (a header of four, without the misfit flag, is read too: the
        samples are four rows, so the two layouts differ in length modulo 4)."""
        a = np.asarray(a, dtype=float).ravel()
        head = _HEADER if (a.size - _HEADER) % 4 == 0 else _HEADER - 1
        if a.size < head:
            return None
        return cls(int(a[0]), a[1], a[2], a[3], a[head:], misfit=head == _HEADER and bool(a[4]))


def _first_row_powers(phi: np.ndarray, n: int) -> np.ndarray:
    """(n, 2): the first row of ``Phi^(k+1)``, k = 0..n-1 (the U bank's first state from a unit start), by the
    recursion ``x_k = tr(Phi) x_(k-1) - det(Phi) x_(k-2)`` (Cayley-Hamilton) run as a filter on an impulse."""
    tr, det = float(np.trace(phi)), float(np.linalg.det(phi))
    first, second = phi[0], (phi @ phi)[0]
    impulse = np.zeros(n)
    impulse[0] = 1.0
    return np.column_stack([lfilter([first[j], second[j] - tr * first[j]], [1.0, -tr, det], impulse)
                            for j in range(2)])


def _held_input(u: np.ndarray, u_last: float) -> np.ndarray:
    """The input the kernel filters: a non-finite sample holds the last finite one."""
    out = np.array(u, dtype=float)
    for k in np.flatnonzero(~np.isfinite(out)):
        out[k] = out[k - 1] if k > 0 else u_last
    return out
