"""The command-line tools' one-line progress bar on stderr (``rsrivc_diagnose`` over data seconds, ``rsrivc_fleet``
over finished bags): ``<prog>: [#####.....] <what is done>  ETA <s> s``, redrawn in place."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import TextIO


class ProgressBar:
    """A one-line progress bar of ``done`` out of ``total`` on a stream, redrawn at most every ``min_interval_s``.

    ``describe(done, total, elapsed_s)`` gives the text after the bar; the estimated time left follows it (from the
    mean rate so far). Disabled, every method does nothing."""

    def __init__(self, prog: str, total: float, stream: TextIO, enabled: bool,
                 describe: Callable[[float, float, float], str], *, width: int = 30,
                 min_interval_s: float = 0.0) -> None:
        self.prog, self.total, self.stream, self.enabled = prog, max(float(total), 1e-12), stream, enabled
        self.describe, self.width, self.min_interval_s = describe, width, min_interval_s
        self.t_start = time.monotonic()
        self._last = -math.inf

    def update(self, done: float, force: bool = False) -> None:
        """Redraw the bar at ``done`` (skipped within ``min_interval_s`` of the last redraw unless ``force``)."""
        if not self.enabled:
            return
        now = time.monotonic()
        if not force and now - self._last < self.min_interval_s:
            return
        self._last = now
        frac = min(max(done / self.total, 0.0), 1.0)
        fill = int(round(frac * self.width))
        elapsed = now - self.t_start
        eta = elapsed / done * (self.total - done) if done > 0 and elapsed > 0 else math.nan
        self.stream.write(f"\r{self.prog}: [{'#' * fill}{'.' * (self.width - fill)}] "
                          f"{self.describe(done, self.total, elapsed)}  ETA {eta:5.1f} s ")
        self.stream.flush()

    def clear(self) -> None:
        """Erase the bar (before a message line)."""
        if self.enabled:
            self.stream.write("\r\033[K")
            self.stream.flush()

    def close(self, done: float | None = None) -> None:
        """Final redraw (at ``done`` when given) and end the line."""
        if self.enabled:
            if done is not None:
                self.update(done, force=True)
            self.stream.write("\n")
            self.stream.flush()
