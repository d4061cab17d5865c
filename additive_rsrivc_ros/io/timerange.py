"""The ``--start``/``--end`` time range of ``rsrivc_identify``, ``rsrivc_diagnose`` and ``rsrivc_fleet``.

One rule (docs/INTERFACE.md "Time ranges"): a value below :data:`ABSOLUTE_FROM_S` (1e9 s, i.e. 2001-09-09) is seconds
from the record's first sample (the ``time_s`` of estimates.csv), a value at or above it an absolute time stamp in
Unix seconds (as ``ros2 bag info`` prints it). The range is ``[start, end)``; either end may be left open. The reader
(:func:`..bagio.read_signals`) skips messages outside it (MCAP chunks outside it are never decompressed); times
in the outputs stay the record's. Bad ranges raise :class:`ValueError` with one line.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

ABSOLUTE_FROM_S = 1e9   # at or above: Unix seconds; below: seconds from the record's first sample


def parse_seconds(text: str, name: str) -> float:
    """A finite number of seconds from a command-line value; ``ValueError`` (one line) otherwise."""
    try:
        v = float(text)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number of seconds, got {text!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"{name} must be a finite number of seconds, got {text!r}")
    return v


@dataclass(frozen=True)
class TimeRange:
    """``[start, end)`` as given (``None``: open); see the module docstring for relative and absolute values."""

    start: float | None = None
    end: float | None = None

    def __post_init__(self) -> None:
        for name, v in (("--start", self.start), ("--end", self.end)):
            if v is not None and not math.isfinite(v):
                raise ValueError(f"{name} must be a finite number of seconds, got {v}")
        if self.start is not None and self.end is not None and \
                (self.start >= ABSOLUTE_FROM_S) == (self.end >= ABSOLUTE_FROM_S) and self.end <= self.start:
            raise ValueError(f"--end ({self.end:.9g}) must be after --start ({self.start:.9g})")

    @classmethod
    def from_args(cls, start: str | float | None, end: str | float | None) -> TimeRange | None:
        """The range of ``--start``/``--end`` (strings or numbers), or ``None`` when neither is given."""
        if start is None and end is None:
            return None
        return cls(None if start is None else parse_seconds(str(start), "--start"),
                   None if end is None else parse_seconds(str(end), "--end"))

    def resolve(self, origin_ns: int, record_end_ns: int, period_s: float) -> ResolvedRange:
        """Absolute ``[start_ns, end_ns)`` for a record whose first sample is at ``origin_ns`` and whose last message
        is at ``record_end_ns``; ``ValueError`` (one line) for a range before, beyond or empty within the record.
        ``period_s``: the sample period (an end one period after the last sample is the record's end)."""
        rec_end_s = (record_end_ns - origin_ns) * 1e-9 + period_s
        t0 = origin_ns * 1e-9
        span = f"the record spans 0 to {rec_end_s:.6g} s (Unix {t0:.9g} to {t0 + rec_end_s:.9g})"

        def rel(v: float | None, default: float) -> float:
            if v is None:
                return default
            return v - origin_ns * 1e-9 if v >= ABSOLUTE_FROM_S else v

        a, b = rel(self.start, 0.0), rel(self.end, rec_end_s)
        tol = 1e-9 + 1e-6 * period_s
        if a < -tol:
            raise ValueError(f"--start {self.start:.9g} is before the record: {span}")
        if a >= rec_end_s - tol:
            raise ValueError(f"--start {self.start:.9g} is beyond the record: {span}")
        if self.end is not None and b > rec_end_s + tol:
            raise ValueError(f"--end {self.end:.9g} is beyond the record: {span}")
        if b <= a:
            raise ValueError(f"--end ({b:.6g} s from the record's start) must be after --start ({a:.6g} s)")
        a = max(a, 0.0)
        return ResolvedRange(a, b, origin_ns, int(origin_ns + round(a * 1e9)), int(origin_ns + round(b * 1e9)),
                             rec_end_s, self)


@dataclass(frozen=True)
class ResolvedRange:
    """A :class:`TimeRange` against one record: seconds from its first sample and absolute ns."""

    start_s: float
    end_s: float
    origin_ns: int
    start_ns: int
    end_ns: int
    record_end_s: float
    given: TimeRange

    def to_dict(self) -> dict[str, Any]:
        """The outputs' ``time_range``: seconds from the record's first sample, Unix seconds, and as given."""
        return {"start_s": self.start_s, "end_s": self.end_s, "record_start_unix_s": self.origin_ns * 1e-9,
                "start_unix_s": self.start_ns * 1e-9, "end_unix_s": self.end_ns * 1e-9,
                "record_duration_s": self.record_end_s, "given": {"start": self.given.start, "end": self.given.end}}
