"""Advisory estimator stress (S5 of :mod:`.faults`): a bounded isolation window after it began.

A residual-variance jump or a projection storm is also the signature of a genuine abrupt structural change, so it
holds no test back. It restricts confirmation instead, for a bounded window from its start: only a deviation that
began with the stress, and the mode's leading one, can then be the fault; once the window has passed every
persistent deviation is judged against the baseline again.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .fault_settings import FaultSetup
from .sequential_test import FaultEvent


class StressEpisode:
    """The current advisory stress episode: its start ``anomaly_since`` (None without one) and whether several
    modes deviate at once under it (``several_modes``)."""

    def __init__(self, setup: FaultSetup) -> None:
        self.setup = setup
        self.anomaly_since: float | None = None   # start of the advisory stress episode, see follow()
        self.several_modes = False                # under stress, several modes deviate at once (see judge_modes)
        self.several_since: float | None = None   # the episode in which they did

    def window_s(self, i: int, q: int) -> float:
        """Length of the isolation window after a stress began: a lightly damped mode's frequency estimate can stay
        in the broadened fit for a few memory lengths before it travels (and no sensor bias moves it)."""
        return (5.0 if q == 0 else 2.0) * float(self.setup.memory_s[i])

    def restricted_until(self, i: int) -> float | None:
        """End of mode ``i``'s isolation window under the current stress episode (None without one)."""
        if self.anomaly_since is None:
            return None
        return self.anomaly_since + max(self.window_s(i, q) for q in range(3))

    def follow(self, t: float, suspect_since: float | None, t_phase: float) -> float | None:
        """Follow the estimator's stress (``suspect_since``: under stress since then, or None) at ``t`` and return the
        episode's start. A stress older than the monitoring phase (from ``t_phase``) is no episode: deviations are
        judged afresh from it. The window never waits for the estimates to return; the episode ends when the
        advisory issue has lapsed and every mode's window has passed."""
        if suspect_since is not None and suspect_since < t_phase:
            suspect_since = None
        if suspect_since is not None:
            self.anomaly_since = suspect_since if self.anomaly_since is None else min(self.anomaly_since,
                                                                                         suspect_since)
        elif self.anomaly_since is not None and t >= max(self.restricted_until(i) or t for i in range(self.setup.K)):
            self.anomaly_since = None
        return self.anomaly_since

    def judge_modes(self, t: float, deviating: np.ndarray, open_events: Sequence[FaultEvent]) -> bool:
        """Under stress, several modes that deviate or travel at once (``deviating``, (K,) bool) and no fault of this
        episode that explains them are no single structural change (a sensor bias refits every mode; a broad mode
        absorbs its lightly damped neighbour's shift before that one's estimate arrives): until the episode's
        isolation windows have passed (:meth:`restricted_until`) the recursion confirms none of them; only the joint
        check, mode by mode, can. Sets and returns ``several_modes``."""
        since = self.anomaly_since
        isolating = since is not None and t < max(self.restricted_until(i) or t for i in range(self.setup.K))
        if not isolating:
            self.several_since = None
        elif int(deviating.sum()) >= 2:
            self.several_since = since
        self.several_modes = bool(isolating and self.several_since == since and not any(
            e.alarm_time_s >= (since or 0.0) for e in open_events))
        return self.several_modes

    def end(self) -> None:
        """No episode (a new baseline)."""
        self.anomaly_since = None
        self.several_since = None

    def load(self, anomaly_since: float | None, several_since: float | None = None) -> None:
        self.anomaly_since = anomaly_since
        self.several_since = several_since

