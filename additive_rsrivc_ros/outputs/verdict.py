"""The offline verdict: did the structural fault tests actually run, and where was each mode blind?

ROS-free, so the node can reuse it. :func:`assess` reads the reports (``time_s``, ``phase``, ``estimating`` and a
``health`` dict with ``hold``, ``reasons``, ``issues`` and the modes' decision states ``modes``) and returns a
:class:`Verdict`: ``monitored_s`` (tests ran against a trusted baseline), ``blind_intervals`` (where and why they
did not: start-up, holds, data gaps, no estimate, untrusted baseline), ``mode_blind`` (a mode's own holds while the
others were tested), ``flagged_model_s`` (tests ran against a model the model-order check flagged) and the
``level`` (docs/INTERFACE.md "Offline verdict"): NO ESTIMATE without an accepted model, FAULT with an event,
DEGRADED when the tests or one mode were blind after the start-up or ran against a flagged model, else OK.

A report at ``t_j`` stands for ``[t_j, t_j + P)`` with ``P`` the median report spacing; a longer silence is a
``no_data`` interval. Times are seconds since the first sample.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from ..core.vocabulary import ALIGN_APPROXIMATE_RELATIVE, EVENTS_HEADER, MODEL_ORDER_FLAGGED, VERDICTS

STARTUP_ISSUES = ("initializing",)       # health issue kinds of a normal start (not a disruption)
STARTUP_REASONS = ("initializing", "starting: finding modes", "no mode guesses: found")   # their reasons
ADVISORY_ISSUES = ("residual_jump", "projection_storm")   # = core.faults.HealthMonitor.ADVISORY_KINDS: never hold
ADVISORY_REASONS = ("residual variance jumped", "projection storm")   # their reason texts (when no 'issues')
WINDOW_BROKEN = ("baseline window restarted", "baseline window paused")   # a data problem broke the baseline window
_SUFFIX = re.compile(r"\s*\((recovering|hold-off)[^)]*\)\s*$")


@dataclass
class BlindInterval:
    """``[start_s, end_s)`` during which the structural tests did not run, with the reason in words."""

    start_s: float
    end_s: float
    kind: str          # initializing | settling | learning | hold | no_data | no_estimate
    reason: str
    startup: bool = False   # part of the normal start-up before the first monitoring

    def to_dict(self) -> dict[str, Any]:
        return {"start_s": round(self.start_s, 6), "end_s": round(self.end_s, 6), "reason": self.reason,
                "kind": self.kind, "startup": self.startup}


@dataclass
class Verdict:
    level: str                 # one of vocabulary.VERDICTS
    text: str
    duration_s: float
    monitored_s: float
    monitoring_start_s: float | None
    blind_intervals: list[BlindInterval] = field(default_factory=list)
    flagged_model_s: float = 0.0          # of monitored_s: the tests ran against a model the order check flagged
    mode_blind: dict[int, list[BlindInterval]] = field(default_factory=dict)   # mode (1-based) -> its own blind
    #                                       intervals while the others were tested (a hold scoped to that mode)

    def __post_init__(self) -> None:
        if self.level not in VERDICTS:
            raise ValueError(f"verdict must be one of {', '.join(VERDICTS)}, got {self.level!r}")

    def to_dict(self) -> dict[str, Any]:
        """The summary.json keys: ``verdict``, ``verdict_text``, ``monitored_s``, ``blind_intervals`` ..."""
        return {"verdict": self.level, "verdict_text": self.text, "monitored_s": round(self.monitored_s, 6),
                "monitoring_start_s": self.monitoring_start_s, "monitored_fraction":
                self.monitored_s / self.duration_s if self.duration_s > 0 else 0.0,
                "blind_intervals": [b.to_dict() for b in self.blind_intervals],
                "flagged_model_s": round(self.flagged_model_s, 6),
                "modes_blind": [{"mode": i, "blind_s": round(sum(b.end_s - b.start_s for b in bl), 6),
                                 "blind_intervals": [b.to_dict() for b in bl]}
                                for i, bl in sorted(self.mode_blind.items())]}

    @property
    def line(self) -> str:
        return f"{self.level}: {self.text}"


def _clean(reason: str) -> str:
    """A health reason without its '(recovering, hold-off until ...)' suffix."""
    return _SUFFIX.sub("", str(reason)).strip()


def _disruption(health: Mapping[str, Any]) -> list[str]:
    """The health reasons that held the tests back for something other than the normal start-up.

    Advisory issues (a residual jump, a projection storm: also the signature of a genuine structural change) never
    hold the tests back (:class:`.core.faults.HealthMonitor`), so they are no disruption even during a hold."""
    if not health.get("hold"):
        return []
    issues = health.get("issues")
    holding = None if issues is None else [str(k) for k in issues if str(k) not in STARTUP_ISSUES + ADVISORY_ISSUES]
    if holding is not None and not holding:
        return []
    reasons = [_clean(r) for r in health.get("reasons", [])]
    reasons = [r for r in reasons if not r.startswith(STARTUP_REASONS + ADVISORY_REASONS)]
    return reasons or [", ".join(holding or ["health hold"])]


def model_flag(health: Mapping[str, Any]) -> str:
    """The model-order check's finding when it flags the model (see the module docstring), or the controller
    invariant ``u = C_d(q)(r - y)`` failing on the data (the configured controller is not the loop's: the closed-loop
    instrument is built from a wrong controller and the pairing of the streams is unverified), else ``''``."""
    mo = health.get("model_order") or {}
    state = str(mo.get("state", "")) if isinstance(mo, Mapping) else ""
    if state in MODEL_ORDER_FLAGGED:
        return str(mo.get("message") or state)
    al = health.get("alignment") or {}
    rel = al.get("relative_residual") if isinstance(al, Mapping) else None
    if isinstance(rel, int | float) and math.isfinite(rel) and rel > ALIGN_APPROXIMATE_RELATIVE:
        return (f"controller invariant u = C_d(q)(r - y) holds only to {rel:.2g} relative: the configured controller "
                "is not the loop's (check controller.numerator/denominator); stream alignment unverified")
    return ""


def _state(rep: Any, seen: dict[str, bool]) -> tuple[str, str]:
    """(kind, reason) of one report; ``kind == 'monitored'`` when the tests ran. Updates ``seen``."""
    health = rep.health or {}
    bad = _disruption(health)
    why = "; ".join(bad[:2])
    if not rep.estimating:
        kind = "no_estimate" if seen["estimate"] else "initializing"
        reason = (f"no estimate ({why or 'estimator re-initializing'})" if seen["estimate"] else
                  "initializing: collecting data for the first model" + (f" ({why})" if why else ""))
        return kind, reason
    seen["estimate"] = True
    phase = str(rep.phase)
    if phase in ("settling", "waiting", "initializing"):
        if seen["baseline_window"] or bad:
            # the cause: what held the tests, else what the health reports (e.g. a residual jump restarted it)
            cause = bad or [r for r in map(_clean, health.get("reasons", [])) if not r.startswith(STARTUP_REASONS)]
            # paused (what was learned is kept) or, with nothing learned yet, restarted
            verb = "paused" if any("baseline window paused" in str(r) for r in health.get("reasons", [])) \
                else "restarted"
            return "settling", f"baseline window {verb} after: {cause[0]}" if cause else f"baseline window {verb}"
        return "settling", "settling: estimator converging before the baseline is learned"
    if phase == "learning":
        seen["baseline_window"] = True
        return "learning", "learning the baseline"
    seen["baseline_window"] = True
    if health.get("hold"):
        return "hold", f"health hold: {why or '; '.join(_clean(r) for r in health.get('reasons', [])[:2])}"
    if health.get("baseline_trusted") is False:
        # the tests run (an event still counts) but their silence is no evidence: the baseline was learned over
        # too little of its window, or the estimate moved within it (core/diagnosis/faults.py)
        return "untrusted", f"baseline untrusted: {_clean(str(health.get('baseline_note') or 'partial window'))}"
    return "monitored", ""


def _period(times: Sequence[float]) -> float:
    d = sorted(b - a for a, b in zip(times[:-1], times[1:], strict=True) if b > a)
    return d[len(d) // 2] if d else math.inf


@dataclass
class Coverage:
    """Where the structural fault tests ran over ``[0, duration_s]`` (see the module docstring)."""

    monitored_s: float
    first_monitored_s: float | None
    blind: list[BlindInterval]
    flagged_model_s: float = 0.0
    flag: tuple[float, str] | None = None     # (time, finding) of the first report whose model was flagged
    mode_blind: dict[int, list[BlindInterval]] = field(default_factory=dict)   # see Verdict.mode_blind


def coverage(reports: Sequence[Any], duration_s: float) -> Coverage:
    """Monitored time, first monitoring time, blind intervals and time under a flagged model over
    ``[0, duration_s]``."""
    times = [float(r.time_s) for r in reports]
    period = _period(times)
    seen = {"estimate": False, "baseline_window": False}
    segs: list[tuple[float, float, str, str]] = []     # (start, end, kind, reason)
    if not reports:
        return Coverage(0.0, None, [BlindInterval(0.0, duration_s, "no_estimate", "no report: no valid data")]
                        if duration_s > 0 else [])
    flagged_s, flag = 0.0, None
    mode_blind: dict[int, list[BlindInterval]] = {}
    if times[0] > 0:
        segs.append((0.0, times[0], "initializing", "initializing: collecting data for the first model"))
    for j, rep in enumerate(reports):
        t0 = times[j]
        t_next = times[j + 1] if j + 1 < len(reports) else max(duration_s, t0)
        kind, reason = _state(rep, seen)
        end = min(t_next, t0 + period) if t_next - t0 > 1.5 * period else t_next
        segs.append((t0, end, kind, reason))
        if kind == "monitored":
            _mode_blind(mode_blind, rep, t0, end)
        if finding := model_flag(rep.health or {}):
            flag = flag or (t0, finding)
            flagged_s += end - t0 if kind == "monitored" else 0.0
        if end < t_next:
            segs.append((end, t_next, "no_data", f"no samples for {t_next - end:.3g} s (data gap)"))
    monitored = sum(b - a for a, b, k, _ in segs if k == "monitored")
    first_mon = next((a for a, _, k, _ in segs if k == "monitored"), None)
    blind: list[BlindInterval] = []
    for a, b, kind, reason in segs:
        if kind == "monitored" or b <= a:
            continue
        if blind and blind[-1].kind == kind and math.isclose(blind[-1].end_s, a, abs_tol=1e-9) and \
                (kind != "settling" or blind[-1].reason == reason or reason.startswith(WINDOW_BROKEN)
                 and blind[-1].reason.startswith(WINDOW_BROKEN)):
            blind[-1].end_s = b
            continue
        blind.append(BlindInterval(a, b, kind, reason))
    _mark_startup(blind, first_mon)
    return Coverage(monitored, first_mon, blind, flagged_s, flag, mode_blind)


def _mode_blind(out: dict[int, list[BlindInterval]], rep: Any, start: float, end: float) -> None:
    """Add ``[start, end)`` to the blind intervals of each mode that the report's decisions show blind (a hold
    scoped to that mode) while the record as a whole was tested; contiguous equal reasons merge."""
    for d in (rep.health or {}).get("modes") or ():
        if str(d.get("state")) != "blind" or end <= start:
            continue
        runs = out.setdefault(int(d["mode"]), [])
        owners = ",".join(sorted({str(h.get("owner")) for h in d.get("holds") or ()})) or "hold"
        if runs and math.isclose(runs[-1].end_s, start, abs_tol=1e-9) and runs[-1].kind == owners:
            runs[-1].end_s = end    # the same holds go on: one interval (its first reason)
        else:
            runs.append(BlindInterval(start, end, owners, _clean(str(d.get("reason", "")))))


def _mode_blind_text(mode_blind: Mapping[int, Sequence[BlindInterval]], limit: int = 2) -> str:
    """'mode 4 blind 9.8 s (20.1–29.9 s: loss of excitation ...)'; ... for every mode with blind time."""
    parts = []
    for i, runs in sorted(mode_blind.items()):
        total = sum(b.end_s - b.start_s for b in runs)
        spans = "; ".join(f"{b.start_s:.1f}–{b.end_s:.1f} s: {b.reason}" for b in runs[:limit])
        more = f"; and {len(runs) - limit} more" if len(runs) > limit else ""
        parts.append(f"mode {i} blind {total:.1f} s ({spans}{more})")
    return "; ".join(parts)


def _mark_startup(blind: list[BlindInterval], first_mon: float | None) -> None:
    """Flag the leading initializing -> settling -> learning run (undisturbed, in order) as start-up."""
    order = {"initializing": 0, "settling": 1, "learning": 2}
    last = -1
    for b in blind:
        if first_mon is not None and b.start_s >= first_mon:
            break
        rank = order.get(b.kind)
        if rank is None or rank < last or b.reason.startswith(WINDOW_BROKEN):
            break
        b.startup, last = True, rank


def _span_text(blind: Sequence[BlindInterval], limit: int = 3) -> str:
    """'12.2–30.0 s (reason); ...' for contiguous runs of blind intervals that are not start-up."""
    runs: list[list[BlindInterval]] = []
    for b in blind:
        if b.startup:
            continue
        if runs and math.isclose(runs[-1][-1].end_s, b.start_s, abs_tol=1e-6):
            runs[-1].append(b)
        else:
            runs.append([b])
    parts = []
    for run in runs[:limit]:
        reasons: list[str] = []
        for b in run:
            if b.kind in ("learning", "initializing"):
                continue
            txt = b.reason
            if txt not in reasons:
                reasons.append(txt)
        if not reasons:
            reasons = [run[0].reason]
        parts.append(f"{run[0].start_s:.1f}–{run[-1].end_s:.1f} s ({'; '.join(reasons[:3])})")
    more = f"; and {len(runs) - limit} more blind interval(s)" if len(runs) > limit else ""
    return "; ".join(parts) + more


def _event_text(events: Sequence[Mapping[str, Any]], limit: int = 4) -> str:
    parts = []
    for e in events[:limit]:
        rel = relative_change(e.get("value"), e.get("baseline"))
        clear = e.get("clear_time_s")
        state = "still open at the end" if clear in (None, "") else f"cleared at {float(clear):.2f} s"
        parts.append(f"mode {e['mode']} {str(e['quantity']).replace('_', ' ')} {e['direction']}"
                     f"{f' {rel:+.1f} %' if rel is not None else ''} since {float(e['onset_time_s']):.2f} s ({state})")
    more = f" and {len(events) - limit} more" if len(events) > limit else ""
    return f"{len(events)} structural fault event(s): " + "; ".join(parts) + more


def relative_change(value: Any, base: Any) -> float | None:
    """Change of ``value`` against ``base`` in % (None when either is not a finite number or the base is 0)."""
    try:
        v, b = float(value), float(base)
    except (TypeError, ValueError):
        return None
    if not (math.isfinite(v) and math.isfinite(b)) or b == 0:
        return None
    return 100.0 * (v - b) / abs(b)


def _events_from_reports(reports: Iterable[Any]) -> list[dict[str, Any]]:
    seen: dict[tuple, dict[str, Any]] = {}
    for rep in reports:
        for e in (*getattr(rep, "events_opened", ()), *getattr(rep, "events_closed", ())):
            seen[(e.mode, e.quantity, e.alarm_time_s)] = {k: getattr(e, k) for k in EVENTS_HEADER}
    return sorted(seen.values(), key=lambda d: (d["onset_time_s"], d["mode"], d["quantity"]))


def _flag_text(cov: Coverage) -> str:
    """'... against a model the model-order check flagged (from 15.0 s: <finding>)' or ''."""
    if cov.flag is None:
        return ""
    t, finding = cov.flag
    who = "the model-order check" if "controller invariant" not in finding else "the controller invariant"
    ran = (f"{cov.flagged_model_s:.1f} s of them against a model {who} flagged"
           if cov.flagged_model_s > 0 else f"{who} flagged the model")
    return f"{ran} (from {t:.1f} s: {finding})"


def assess(reports: Sequence[Any], duration_s: float,
           events: Sequence[Mapping[str, Any]] | None = None) -> Verdict:
    """The verdict of a record from its reports (see the module docstring). ``events``: the structural events
    as dicts (events.csv columns); default: collected from the reports' ``events_opened``/``events_closed``."""
    reports = list(reports)
    events = _events_from_reports(reports) if events is None else list(events)
    duration_s = max(float(duration_s), float(reports[-1].time_s) if reports else 0.0)
    cov = coverage(reports, duration_s)
    monitored, first_mon, blind = cov.monitored_s, cov.first_monitored_s, cov.blind
    ran = f"fault tests ran for {monitored:.1f} s of {duration_s:.1f} s"
    if first_mon is not None:
        ran += f" (first from {first_mon:.1f} s)"
    flagged = _flag_text(cov)
    disrupted = [b for b in blind if not b.startup]
    spans = _span_text(blind)

    def verdict(level: str, text: str) -> Verdict:
        return Verdict(level, text, duration_s, monitored, first_mon, blind, cov.flagged_model_s, cov.mode_blind)

    modes_blind = _mode_blind_text(cov.mode_blind)

    if not any(r.estimating for r in reports):
        last = next((d for r in reversed(reports) if (d := _disruption(r.health or {}))), None)
        why = last[0] if last else (blind[-1].reason if blind else "no data")   # e.g. why no modes were found
        return verdict("NO ESTIMATE", f"the estimator never had an accepted model in {duration_s:.1f} s of data "
                       f"({why}); fault tests did not run.")
    if events:
        return verdict("FAULT", f"{_event_text(events)}; {ran}" + (f", {flagged}" if flagged else "")
                       + (f"; blind {spans}" if disrupted else "") + (f"; {modes_blind}" if modes_blind else "") + ".")
    if monitored <= 0.0:
        end = blind[-1].reason if blind else ""
        return verdict("DEGRADED", f"fault tests never ran: no trusted baseline in {duration_s:.1f} s of data (at "
                       f"the end: {end})" + (f"; {flagged}" if flagged else "") + (f"; blind {spans}" if disrupted
                                                                                  else "")
                       + "; structural faults could not be tested.")
    if disrupted or cov.flagged_model_s > 0 or modes_blind:
        return verdict("DEGRADED", ran + (f", {flagged}" if cov.flagged_model_s > 0 else "")
                       + (f"; blind {spans}" if disrupted else "") + (f"; {modes_blind}" if modes_blind else "")
                       + "; no structural fault detected while they ran"
                       + ("; a misfitting model can hide a fault" if cov.flagged_model_s > 0 else "") + ".")
    return verdict("OK", f"no structural fault detected in the {monitored:.1f} s the fault tests ran (from "
                   f"{first_mon:.1f} s to the end of the {duration_s:.1f} s record; before that the start-up: "
                   "initialization, settling, learning the baseline)"
                   + (f"; earlier, {flagged}, but not while they ran" if flagged else "") + ".")
