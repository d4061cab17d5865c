"""Composition of the monitor's /diagnostics statuses, ROS-free (the node converts the records: ros/convert.py).

A status is a :class:`StatusRecord` (name, level, message, key/values). Its level and message are merged from
:class:`Finding` s the way diagnostic_updater's ``DiagnosticStatusWrapper.mergeSummary`` merges summaries: the
highest level wins and the texts are joined with ``"; "``. Two differences, both kept from the node's published
text: every finding's text is joined in order (mergeSummary drops the text of OK-level summaries), and two
findings override the merged level instead of competing with it (:func:`estimator_summary`: silence is STALE, a
wrong message type is ERROR, whatever the estimate says).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from ..core.diagnosis.faults import Level


@dataclass(frozen=True)
class Finding:
    """One contribution to a status: its level and its text (``None``: a level without a text)."""

    level: Level
    text: str | None = None


@dataclass
class StatusRecord:
    """One /diagnostics status before conversion: name, level, message and the ordered key/values."""

    name: str
    level: Level
    message: str
    values: dict[str, Any] = field(default_factory=dict)


def merge(findings: Sequence[Finding]) -> tuple[Level, str]:
    """``mergeSummary`` of ``findings``: the highest level (OK when there are none) and every text, in order,
    joined with ``"; "`` ('' when no finding has a text)."""
    level = max((f.level for f in findings), default=Level.OK)
    return Level(level), "; ".join(f.text for f in findings if f.text is not None)


def estimator_summary(health: Finding, health_reasons: Sequence[str], *, recent_event: Finding | None = None,
                      lasting: Sequence[str] = (), internal_error: str = "", silent: str = "",
                      wrong_types: str = "") -> tuple[Level, str]:
    """Level and reasons text of the ``<node>: estimator`` status.

    ``health``: the estimator's own level (STALE before any report) with ``health_reasons``; ``recent_event``: an
    input event of the last seconds (WARN; its text is None when it repeats a lasting reason); ``lasting``: open
    input problems (WARN each); ``internal_error``: the last worker/publisher exception (ERROR). The highest level
    wins, except: a STALE estimator yields to lasting input problems (no estimate yet but data flows: the input
    problem is the news); ``silent`` (a text naming the silent topics) makes the status STALE and ``wrong_types``
    ERROR, whatever else holds; their texts come first (wrong types, then silence).
    """
    base = health.level if not (health.level == Level.STALE and lasting) else Level.OK
    findings = [Finding(base), *(Finding(Level.OK, r) for r in health_reasons)]
    if recent_event is not None:
        findings.append(recent_event)
    findings += [Finding(Level.WARN, r) for r in lasting]
    if internal_error:
        findings.append(Finding(Level.ERROR, f"internal error: {internal_error}"))
    if silent:
        findings.insert(0, Finding(Level.OK, silent))
    if wrong_types:
        findings.insert(0, Finding(Level.OK, wrong_types))
    level, text = merge(findings)
    if wrong_types:
        level = Level.ERROR
    elif silent:
        level = Level.STALE
    return level, text


def mode_summary(report: Finding | None, *, silent: str = "", estimating: bool = False,
                 looking: bool = False) -> tuple[Level, str]:
    """Level and message of a ``<node>: mode <i>`` status.

    ``report``: the mode's fault level and message when the newest report describes this mode (None: no report,
    or one with another number of modes); ``silent``: text naming the silent topics (STALE, first); without an
    estimate (``estimating`` False) the mode is STALE "initializing"; with an estimate but no report for this mode,
    STALE "initializing" once the node has been spinning (``looking``), else "starting"."""
    if silent:
        return Level.STALE, silent
    if not estimating:
        return Level.STALE, "initializing"
    if report is not None:
        return report.level, report.text or ""
    return Level.STALE, "initializing" if looking else "starting"
