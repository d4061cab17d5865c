"""Does ``loop_rate_hz`` agree with the samples' own time stamps? (a wrong rate scales every frequency).

Samples that carry their own time (header-stamped messages, a bag's stamps) are spaced ``1/loop_rate_hz`` apart
except at gaps. :class:`StampSpacing` keeps the last accepted stamps and compares the median spacing, which gaps and
the odd jittered stamp do not move, with the configured period. A disagreement beyond ``TOLERANCE`` is a wrong time
scale: the model's frequencies would be off by the same factor, so the pipeline publishes no number while it lasts.
"""

from __future__ import annotations

import numpy as np

TOLERANCE = 0.02     # relative disagreement of the median spacing with 1/loop_rate_hz (as the arrival-rate check)
WINDOW = 2048        # stamps kept (the last ones)
MIN_INTERVALS = 256  # spacings needed before judging


class StampSpacing:
    """Median stamp spacing of the last ``WINDOW`` accepted samples against ``1/rate_hz``."""

    def __init__(self, rate_hz: float) -> None:
        self.rate_hz = float(rate_hz)
        self._t = np.empty(0)
        self.median_hz = float("nan")
        self.error = ""             # one line while the stamps contradict loop_rate_hz, else ""

    def add(self, t: np.ndarray) -> bool:
        """Take accepted (increasing) stamps in seconds; True when the verdict (:attr:`error`) changed."""
        if t.size == 0:
            return False
        self._t = np.concatenate((self._t, np.asarray(t, float)))[-WINDOW:]
        if self._t.size <= MIN_INTERVALS:
            return False
        spacing = float(np.median(np.diff(self._t)))
        if not spacing > 0.0:
            return False
        self.median_hz = 1.0 / spacing
        was = self.error
        if abs(self.median_hz / self.rate_hz - 1.0) > TOLERANCE:
            self.error = (f"loop_rate_hz {self.rate_hz:g} disagrees with the samples' stamps (median spacing "
                          f"{1e3 * spacing:.4g} ms, {self.median_hz:.0f} Hz): no estimate is published until they "
                          "agree")
        else:
            self.error = ""
        return self.error != was

    def restart(self) -> None:
        """A break in the stamps' history (clock step, restart): judge on new stamps only."""
        self._t = np.empty(0)
