"""Nonparametric plant frequency response (FRF) from recorded r, u, y with its uncertainty.

Welch averaging over ``n_d`` Hann segments with 50 % overlap. Closed loop: the indirect estimate ``G = S_yr / S_ur``
(``r`` is uncorrelated with the fed-back noise, so it is consistent where the direct ``S_yu / S_uu`` tends to ``-1/C``;
Pintelon & Schoukens, *System Identification*, §2.6, §8.3); open loop the H1 estimate ``S_yu / S_uu``. With ``w = y - G
u`` (the output disturbance in both loops) its variance is ``var(G) = S_ww S_rr / (n_d |S_ur|^2)``, the H1 formula ``(1
- gamma^2) / (n_d gamma^2) |G|^2`` in open loop (Bendat & Piersol, *Random Data*, eq. 9.90), with ``n_d / (1 + 2 c^2)``
effective averages for overlapping windows (Welch 1967). A bin is *valid* where the excitation reaches it, ``u`` and
``y`` are coherent with it above chance (Bonferroni over the bins) and the relative std is below ``max_relative_std``;
elsewhere the FRF must not be used. The estimate is the sampled plant's response with the zero-order hold and the input
delay; :func:`discrete_model_frf` gives the same for a parametric model.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..model import SubmodelStructure

HANN_OVERLAP_CORRELATION = 0.167  # correlation of two 50 %-overlapping Hann windows (Welch 1967)


@dataclass
class FRFEstimate:
    """FRF estimate: frequencies, complex ``G``, coherence, variance of ``G`` and validity per frequency."""

    freqs_hz: np.ndarray
    G: np.ndarray
    coherence: np.ndarray  # |S_yr|^2/(S_rr S_yy) in closed loop (with r), |S_yu|^2/(S_uu S_yy) in open loop
    variance: np.ndarray  # E|G_hat - G|^2 (complex variance) from the noise (H1 formula)
    resolution_error: np.ndarray  # bound of the leakage/resolution bias: largest change of G to a neighbour bin
    valid: np.ndarray
    excitation: np.ndarray  # auto-spectrum of the excitation (r or u)
    n_averages: float  # effective number of independent averages
    rate_hz: float
    closed_loop: bool
    nperseg: int
    #: valid bins whose excitation is mostly Hann leakage of a neighbouring line (:func:`line_spectrum`): they
    #: still locate a resonance, but their ``G`` leans towards the line's value beyond ``uncertainty``; a plot of
    #: the FRF with error bars shows ``valid & ~leakage``
    leakage: np.ndarray | None = None

    @property
    def std(self) -> np.ndarray:
        """Noise standard deviation of ``G`` (complex)."""
        return np.sqrt(self.variance)

    @property
    def uncertainty(self) -> np.ndarray:
        """``sqrt(variance + resolution_error^2)``: the noise and the leakage bias of a Hann window, which averages
        ``G`` over about two bins either side (a periodic reference line between two bins is seen at its own
        frequency, not the bin's)."""
        return np.sqrt(self.variance + self.resolution_error**2)

    @property
    def resolution_hz(self) -> float:
        return self.rate_hz / self.nperseg

    @property
    def band_hz(self) -> tuple[float, float] | None:
        """Lowest and highest valid frequency (``None`` when nothing is valid)."""
        if not np.any(self.valid):
            return None
        f = self.freqs_hz[self.valid]
        return float(f[0]), float(f[-1])

    def summary(self) -> dict[str, Any]:
        band = self.band_hz
        return {"method": "indirect S_yr/S_ur" if self.closed_loop else "H1 S_yu/S_uu",
                "window": "hann", "overlap": 0.5, "nperseg": self.nperseg, "resolution_hz": self.resolution_hz,
                "n_averages": self.n_averages, "band_hz": list(band) if band else None,
                "n_valid": int(np.sum(self.valid))}


def longest_finite(first: np.ndarray | None, second: np.ndarray, *rest: np.ndarray | None) -> slice:
    """The longest stretch where every given signal (``None``: absent) is finite; the second sets the length."""
    ok = np.ones(second.size, dtype=bool)
    for s in (first, second, *rest):
        if s is not None:
            ok &= np.isfinite(s)
    edges = np.flatnonzero(np.diff(np.concatenate(([0], ok.astype(int), [0]))))
    if edges.size == 0:
        return slice(0, 0)
    starts, ends = edges[::2], edges[1::2]
    j = int(np.argmax(ends - starts))
    return slice(int(starts[j]), int(ends[j]))


def _segments(x: np.ndarray, nperseg: int) -> np.ndarray:
    """Hann-windowed, mean-removed segments with 50 % overlap, as rows of their FFT (one-sided)."""
    step = nperseg // 2
    n_seg = 1 + (x.size - nperseg) // step
    idx = np.arange(nperseg)[None, :] + step * np.arange(n_seg)[:, None]
    seg = x[idx]
    seg = seg - seg.mean(axis=1, keepdims=True)
    win = np.hanning(nperseg + 1)[:-1]  # periodic Hann
    return np.fft.rfft(seg * win, axis=1)


def default_nperseg(n: int, min_averages: int = 8) -> int:
    """Largest power of two giving at least ``min_averages`` 50 %-overlapping segments (at least 16)."""
    target = max(16, int(2 * n / (min_averages + 1)))
    return max(16, 1 << int(np.floor(np.log2(target))))


def coherence_threshold(n_segments: int, alpha: float = 0.01) -> float:
    """Coherence exceeded with probability ``alpha`` by ``n_segments`` averages of uncorrelated signals."""
    return 1.0 - alpha ** (1.0 / max(n_segments - 1, 1))


def estimate_frf(u: Sequence[float] | np.ndarray, y: Sequence[float] | np.ndarray, rate_hz: float,
                 r: Sequence[float] | np.ndarray | None = None, *,
                 nperseg: int | None = None, excitation_floor: float = 1e-8, max_relative_std: float = 0.3,
                 min_averages: int = 16, alpha: float | None = None) -> FRFEstimate:
    """FRF of the plant from ``u`` to ``y`` (indirect through ``r`` when given). See the module docstring."""
    u = np.asarray(u, dtype=float)
    y = np.asarray(y, dtype=float)
    if u.shape != y.shape or u.ndim != 1:
        raise ValueError("u and y must be one-dimensional and of equal length")
    x = u if r is None else np.asarray(r, dtype=float)
    if x.shape != u.shape:
        raise ValueError("r must have the length of u and y")
    if not (np.all(np.isfinite(u)) and np.all(np.isfinite(y)) and np.all(np.isfinite(x))):
        raise ValueError("r, u and y must be finite for the FRF")
    if nperseg is None:  # min_averages, unless that makes the resolution coarser than 0.5 Hz: then down to 8
        nperseg = max(default_nperseg(u.size, min_averages),
                      min(default_nperseg(u.size, min(8, min_averages)), int(2 * rate_hz)))
    if nperseg < 16 or u.size < 2 * nperseg:
        raise ValueError(f"record of {u.size} samples too short for FRF segments of {nperseg} (need 2 segments)")
    X, U, Y = _segments(x, nperseg), _segments(u, nperseg), _segments(y, nperseg)
    n_seg = X.shape[0]
    S_xx = np.mean(np.abs(X) ** 2, axis=0)
    S_yy = np.mean(np.abs(Y) ** 2, axis=0)
    S_uu = np.mean(np.abs(U) ** 2, axis=0)
    S_yx = np.mean(Y * np.conj(X), axis=0)
    S_ux = np.mean(U * np.conj(X), axis=0)
    S_yu = np.mean(Y * np.conj(U), axis=0)
    tiny = np.finfo(float).tiny
    with np.errstate(divide="ignore", invalid="ignore"):
        G = S_yx / S_ux
        # S_ww of w = y - G u, with the fitted G removing one degree of freedom per frequency
        S_ww = S_yy - 2.0 * np.real(np.conj(G) * S_yu) + np.abs(G) ** 2 * S_uu
        S_ww = np.maximum(S_ww, 0.0) * n_seg / max(n_seg - 1, 1)
        n_eff = n_seg / (1.0 + 2.0 * HANN_OVERLAP_CORRELATION**2)
        var = S_ww * S_xx / (n_eff * np.maximum(np.abs(S_ux) ** 2, tiny))
        coh = np.abs(S_yx) ** 2 / np.maximum(S_xx * S_yy, tiny)
        coh_u = np.abs(S_ux) ** 2 / np.maximum(S_xx * S_uu, tiny)
    freqs = np.fft.rfftfreq(nperseg, 1.0 / rate_hz)
    finite = np.isfinite(G) & np.isfinite(var)
    inner = (freqs > 0) & (freqs < rate_hz / 2.0)
    floor = excitation_floor * np.max(S_xx[inner]) if np.any(inner) else np.inf
    rel = np.sqrt(np.where(finite, var, np.inf)) / np.maximum(np.abs(np.where(finite, G, 0.0)), tiny)
    n_eff_int = max(int(np.floor(n_eff)), 2)
    alpha = min(0.01, 1.0 / freqs.size) if alpha is None else alpha  # Bonferroni: < 1 spurious bin per record
    coherent = (coh > coherence_threshold(n_eff_int, alpha)) & (coh_u > coherence_threshold(n_eff_int, alpha))
    leakage, offset = line_spectrum(S_xx)
    valid = inner & finite & (S_xx > floor) & coherent & (rel < max_relative_std)
    freqs = freqs + offset * (rate_hz / nperseg)     # a line's estimate belongs to the line's frequency
    G = np.where(finite, G, 0.0)
    var = np.where(finite, var, np.inf)
    return FRFEstimate(freqs, G, np.clip(coh, 0.0, 1.0), var, _resolution_error(G, valid & ~leakage), valid, S_xx,
                       float(n_eff), float(rate_hz), r is not None, nperseg, leakage & valid)


def line_spectrum(S_xx: np.ndarray, prominence: float = 100.0, margin: float = 10.0, reach: int = 64,
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Spectral *lines* of a periodic excitation (square-wave setpoints, multisines) among the bins: which bins are
    their Hann leakage, and each line's offset from its bin. Returns ``(leakage, offset_bins)``.

    A line is a local maximum (+-2 bins) at least ``prominence`` times the median of the bins 3 to 8 away on both
    sides (averaged broadband spectra fluctuate by a few times, never by 100: a band-limited noise has no lines).

    * Leakage: at a bin near a line, ``S_yr / S_ur`` leans towards ``G`` at the line's frequency. The
      power a line ``P_j`` leaks into bin ``k`` is bounded by ``P_j`` for ``|k - j| <= 2`` (the main lobe) and by
      the Hann sidelobe envelope ``P_j / (pi^2 d^6)`` at ``d = |k - j| >= 3`` (Harris 1978); a bin is
      leakage-dominated when its own excitation is less than ``margin`` times that bound.
    * Offset: a line between bins ``k`` and ``k +- 1`` lies at ``k +- delta`` with ``delta = (2 a - 1) / (a + 1)``,
      ``a = |X_{k+-1}| / |X_k|`` the amplitude ratio to the larger neighbour (the Hann window's interpolation,
      Grandke 1983; ``|X| = sqrt(S_xx)`` for a line). The line bin's estimate is ``G`` at ``k +- delta``.
    """
    n = S_xx.size
    leakage, offset = np.zeros(n, dtype=bool), np.zeros(n)
    if n < 20:
        return leakage, offset
    side = 8
    pad = np.pad(S_xx, side, mode="edge")
    win = np.lib.stride_tricks.sliding_window_view(pad, 2 * side + 1)
    around = np.median(np.concatenate((win[:, :side - 2], win[:, side + 3:]), axis=1), axis=1)
    local = np.all(win[:, side - 2:side + 3] <= S_xx[:, None], axis=1)
    line = local & (S_xx > prominence * around) & (S_xx > 0)
    line[0] = False
    if not line.any():
        return leakage, offset
    d = np.arange(-reach, reach + 1, dtype=float)
    w = np.where(np.abs(d) >= 3, 1.0 / (np.pi**2 * np.maximum(np.abs(d), 1.0) ** 6), 1.0)
    w[reach] = 0.0                                   # a line does not leak into itself
    leak = np.convolve(np.where(line, S_xx, 0.0), w, mode="same")
    leakage = S_xx < margin * leak
    amp = np.sqrt(np.maximum(S_xx, 0.0))
    for k in np.flatnonzero(line):
        if k < 2:                                    # the left neighbour is the (mean-removed) DC bin: no interpolation
            continue
        left = amp[k - 1]
        right = amp[k + 1] if k + 1 < n else 0.0
        sign, ratio = (1.0, right / amp[k]) if right >= left else (-1.0, left / amp[k])
        offset[k] = sign * max(0.0, (2.0 * ratio - 1.0) / (ratio + 1.0))
    return leakage, offset


def _resolution_error(G: np.ndarray, valid: np.ndarray, reach: int = 2) -> np.ndarray:
    """Largest ``|G(k + j) - G(k)|``, ``0 < |j| <= reach``, over valid neighbours of bin ``k``: the bias bound of a
    Hann window, whose main lobe spans two bins either side (a periodic reference line up to two bins away is seen
    at its own frequency)."""
    err = np.zeros(G.size)
    for j in range(1, reach + 1):
        d = np.abs(G[j:] - G[:-j])
        d = np.where(valid[j:] & valid[:-j], d, 0.0)
        err[j:] = np.maximum(err[j:], d)
        err[:-j] = np.maximum(err[:-j], d)
    return err


def discrete_model_frf(thetas: Sequence[np.ndarray], structures: Sequence[SubmodelStructure], rate_hz: float,
                       freqs_hz: np.ndarray, input_delay: int = 0) -> np.ndarray:
    """``G_d(e^{j w h})`` of the exact ZOH discretization of the additive model with the input delay (the quantity
    :func:`estimate_frf` estimates)."""
    from ..plant import discrete_mode_blocks

    w = 2.0 * np.pi * np.asarray(freqs_hz, dtype=float) / rate_hz
    zs = np.exp(1j * w)
    out = np.zeros(zs.size, dtype=complex)
    for phi, gam, c in discrete_mode_blocks(list(thetas), list(structures), rate_hz):
        # c_i (zI - Phi_i)^-1 Gamma_i at every z in one batched solve per submodel: the plant's Phi is block-
        # diagonal, and one solve of the whole (delay states included) cost 8x more at 2048 bins
        x = np.linalg.solve(zs[:, None, None] * np.eye(phi.shape[0]) - phi,
                            np.broadcast_to(gam, (zs.size, gam.size))[..., None])
        out += x[..., 0] @ c
    return out * np.exp(-1j * w * int(input_delay))    # the delay line: z^-d


def model_frf_on_bins(frf: FRFEstimate, thetas: Sequence[np.ndarray], structures: Sequence[SubmodelStructure],
                      input_delay: int = 0) -> np.ndarray:
    """:func:`discrete_model_frf` on every bin of ``frf`` (0 at 0 Hz, which is never valid and where a rigid body's
    response is infinite): what the misfit ``G - G_model`` is formed from (model-order check, residual start)."""
    out = np.zeros(frf.freqs_hz.size, dtype=complex)
    pos = frf.freqs_hz > 0.0
    out[pos] = discrete_model_frf(thetas, structures, frf.rate_hz, frf.freqs_hz[pos], input_delay)
    return out
