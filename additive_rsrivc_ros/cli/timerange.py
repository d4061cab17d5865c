"""``--start``/``--end`` of the offline tools: the arguments and their one rule (:mod:`..timerange`)."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING, Any

from ..io.timerange import ABSOLUTE_FROM_S, TimeRange

if TYPE_CHECKING:
    from ..core.monitor.pipeline import MonitorPipeline
    from ..io.bagio import Signals
    from ..outputs.verdict import Verdict

RANGE_HELP = ("seconds from the record's first sample, or an absolute time stamp in Unix seconds when the value is "
              f"{ABSOLUTE_FROM_S:.0f} or more; the samples outside [start, end) are not read")


def add_range_arguments(ap: argparse.ArgumentParser) -> None:
    """``--start S`` and ``--end S`` (strings: checked by :func:`range_of`, so a bad value is one line)."""
    ap.add_argument("--start", default=None, metavar="S", help=f"use the record from S on ({RANGE_HELP})")
    ap.add_argument("--end", default=None, metavar="S", help="use the record up to S (same rule as --start)")


def range_of(start: str | float | None, end: str | float | None) -> TimeRange | None:
    """The :class:`TimeRange` of the arguments (``None``: the whole record); ``ValueError`` with one line."""
    return TimeRange.from_args(start, end)


def range_text(time_range: dict[str, Any] | None) -> str:
    """`` (65-120 s of the 240 s record)`` for a range, ``''`` for the whole record."""
    if not time_range:
        return ""
    return (f" ({time_range['start_s']:.6g}-{time_range['end_s']:.6g} s of the {time_range['record_duration_s']:.6g} s "
            "record)")


def anchor_pipeline(pipe: MonitorPipeline, sig: Signals) -> None:
    """A range: the pipeline's time origin is the record's first sample (``Signals.t`` counts from it), so its
    reports, events and notes carry the record's time, as without a range. (``t0`` is the pipeline's time origin,
    set by its first sample otherwise.)"""
    if sig.time_range:
        pipe.t0 = 0.0


def verdict_in_range(verdict: Verdict, time_range: dict[str, Any] | None) -> Verdict:
    """The verdict of a range: the time before it is no blind interval (it was not asked for), the monitored
    fraction counts the range only, and the text says which range."""
    if not time_range:
        return verdict
    a = float(time_range["start_s"])
    kept = []
    for b in verdict.blind_intervals:
        if b.end_s > a + 1e-9:
            b.start_s = max(b.start_s, a)
            kept.append(b)
    verdict.blind_intervals = kept
    verdict.duration_s = max(verdict.duration_s - a, 0.0)
    verdict.text = verdict.text.rstrip(".") + f"; analysed{range_text(time_range)}."
    return verdict
