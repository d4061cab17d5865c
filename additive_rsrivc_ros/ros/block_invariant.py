"""Closed-loop consistency check of block rows: the controller invariant ``u = C_d(q)(r - y)`` (ROS-free).

[RA-SRIVC] eq. 10 as ``D(q^-1) u = N(q^-1)(r - y)``, evaluated on released rows a few times a second (each
``INVARIANT_EVERY_S`` of data) over adjacent indices; its median relative residual is reported, and a residual above
``INVARIANT_WARN`` (rounding gives ~1e-16) is a lasting reason: the rows do not fit the configured controller or
their columns are mixed up. A consistency check only: rows are never re-paired by it.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..core.input.alignment import invariant_residual

INVARIANT_EVERY_S = 0.1      # the invariant is evaluated on the block that completes this much data since the last
INVARIANT_WARN = 1e-6        # relative invariant residual above which the block rows do not fit the controller


class ControllerInvariant:
    """The invariant of ``controller`` (None, or open loop: nothing is checked) on released rows."""

    def __init__(self, rate_hz: float, controller: Any = None) -> None:
        self.rate = float(rate_hz)
        self._den: np.ndarray | None = None
        self._num: np.ndarray | None = None
        if controller is not None:
            self._den, self._num = np.asarray(controller.den, float), np.asarray(controller.num, float)
        self._order = 0 if self._den is None or self._num is None else max(self._den.size, self._num.size) - 1
        self._tail: tuple[np.ndarray, np.ndarray] | None = None     # last released rows for the invariant
        self.relative = math.nan
        self._rows = 0

    def forget_tail(self) -> None:
        """The index run ended (controller restart): the next rows are not adjacent to the last ones."""
        self._tail = None

    def check(self, k: np.ndarray, vals: np.ndarray) -> None:
        """Relative residual of ``D(q^-1) u = N(q^-1)(r - y)`` over adjacent rows (indices ``k``, values r, u, y)."""
        p = self._order
        if self._den is None or self._num is None:
            return
        tail, self._tail = self._tail, ((k[-p:].copy(), vals[-p:].copy()) if p else None)
        self._rows += k.size
        if self._rows < INVARIANT_EVERY_S * self.rate:     # a consistency check: a few times a second is enough
            return
        self._rows = 0
        if tail is not None and tail[0].size and tail[0][-1] == k[0] - 1:
            k = np.concatenate((tail[0], k))
            vals = np.concatenate((tail[1], vals))
        if k.size <= p:
            return
        e, scale = invariant_residual(self._den, self._num, vals[:, 0], vals[:, 1], vals[:, 2])
        ok = (k[p:] - k[:k.size - p] == p) & np.isfinite(e) & (scale > 0)
        if ok.any():
            self.relative = float(np.median(np.abs(e[ok]) / scale[ok]))

    def reason(self) -> str:
        """A lasting WARN reason while the rows do not fit the controller, else ''."""
        rel = self.relative
        if math.isfinite(rel) and rel > INVARIANT_WARN:
            return (f"controller invariant u = C_d(q)(r - y) holds only to {rel:.2g} relative on the block rows "
                    "(rounding gives ~1e-16): check controller.numerator/denominator and the column order index, "
                    "reference, input, output")
        return ""
