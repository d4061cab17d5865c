"""The known discrete-time feedback controller ``C_d(q)`` of the closed loop ([RA-SRIVC] eq. 10).

Coefficients are given in ascending powers of ``q^-1``:
``C_d(q) = (c0 + c1 q^-1 + ...) / (d0 + d1 q^-1 + ...)`` and the control law is
``u(t_k) = C_d(q) (r(t_k) - y(t_k))``. Example ([RA-SRIVC] §5 corrected, erratum 1 in docs/DESIGN.md):
``C_d = (0.02329 q^2 - 0.02058 q + 0.00454) / (q^2 - q)`` is
``numerator = [0.02329, -0.02058, 0.00454]``, ``denominator = [1, -1, 0]``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class DiscreteController:
    """A causal SISO discrete-time controller in ascending powers of ``q^-1`` (``d0 != 0``)."""

    numerator: tuple[float, ...]
    denominator: tuple[float, ...] = field(default=(1.0,))

    def __post_init__(self) -> None:
        num = np.asarray(self.numerator, dtype=float)
        den = np.asarray(self.denominator, dtype=float)
        if num.size == 0 or den.size == 0:
            raise ValueError("controller numerator and denominator must be non-empty")
        if not (np.all(np.isfinite(num)) and np.all(np.isfinite(den))):
            raise ValueError("controller coefficients must be finite")
        if den[0] == 0.0:
            raise ValueError("controller denominator[0] (coefficient of q^0) must be non-zero (causal controller)")
        object.__setattr__(self, "numerator", tuple(float(v) for v in num / den[0]))
        object.__setattr__(self, "denominator", tuple(float(v) for v in den / den[0]))

    @property
    def num(self) -> np.ndarray:
        return np.asarray(self.numerator)

    @property
    def den(self) -> np.ndarray:
        return np.asarray(self.denominator)

    @property
    def order(self) -> int:
        return max(len(self.numerator), len(self.denominator)) - 1

    def apply(self, error: np.ndarray) -> np.ndarray:
        """``u = C_d(q) e`` from rest (scipy.signal.lfilter)."""
        from scipy import signal  # lazy: scipy.signal costs ~1 s at import, the node needs a fast start

        return signal.lfilter(self.num, self.den, np.asarray(error, dtype=float))

    def frequency_response(self, freqs_hz: np.ndarray, rate_hz: float) -> np.ndarray:
        """``C_d(e^{j w h})`` at the given frequencies."""
        from scipy import signal

        w = 2.0 * np.pi * np.asarray(freqs_hz, dtype=float) / rate_hz
        _, h = signal.freqz(self.num, self.den, worN=w)
        return h
