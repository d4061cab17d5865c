"""verdict.assess on synthetic Report sequences: OK, FAULT, DEGRADED (with its blind intervals), NO ESTIMATE.

The reports mimic core.pipeline.Report at a 10 Hz publish rate: ``time_s``, ``phase``, ``estimating`` and a
``health`` dict with ``hold``, ``reasons``, ``issues``. Every case also checks the partition invariant: monitored
time plus blind intervals cover the record exactly once.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from additive_rsrivc_ros.outputs import report as rp
from additive_rsrivc_ros.outputs.verdict import assess

P = 0.1   # publish period [s]
INIT = {"hold": True, "issues": ["initializing"],
        "reasons": ["initializing: collecting 2 s of valid data for the offline initialization"]}
HEALTHY = {"hold": False, "issues": [], "reasons": []}


def _run(t0: float, t1: float, phase: str, estimating: bool = True, health: dict | None = None) -> list:
    n = int(round((t1 - t0) / P))
    h = HEALTHY if health is None else health
    return [SimpleNamespace(time_s=round(t0 + P * j, 9), phase=phase, estimating=estimating, health=dict(h),
                            events_opened=[], events_closed=[], modal=np.zeros((1, 6)), baseline=np.zeros((1, 3)),
                            flags=np.zeros((1, 3), bool)) for j in range(n)]


def _startup(t_mon: float = 6.0) -> list:
    """initializing 0-2 s, settling 2-4 s (start-up hold until 3 s), learning 4-t_mon s."""
    return (_run(0, 2, "initializing", False, INIT) + _run(2, 3, "settling", True, INIT) + _run(3, 4, "settling")
            + _run(4, t_mon, "learning"))


def _partition_ok(v, duration: float) -> None:
    blind = sum(b.end_s - b.start_s for b in v.blind_intervals)
    assert v.monitored_s + blind == pytest.approx(duration, abs=1e-6)
    ends = [(b.start_s, b.end_s) for b in v.blind_intervals]
    assert all(a < b for a, b in ends)
    assert all(b0 <= a1 + 1e-9 for (_, b0), (a1, _) in zip(ends[:-1], ends[1:], strict=True))


def test_ok_after_a_normal_startup() -> None:
    reps = _startup() + _run(6, 20, "monitoring")
    v = assess(reps, 20.0)
    assert v.level == "OK"
    assert v.monitored_s == pytest.approx(14.0, abs=1e-6) and v.monitoring_start_s == pytest.approx(6.0)
    assert [b.kind for b in v.blind_intervals] == ["initializing", "settling", "learning"]
    assert all(b.startup for b in v.blind_intervals)
    assert "in the 14.0 s the fault tests ran (from 6.0 s to the end of the 20.0 s record" in v.text
    _partition_ok(v, 20.0)


def test_advisory_warning_without_hold_keeps_ok() -> None:
    """A residual jump (advisory, also the signature of a genuine change) does not blind the tests."""
    warn = {"hold": False, "issues": ["residual_jump"], "reasons": ["residual variance jumped x40"], "level": 1}
    v = assess(_startup() + _run(6, 12, "monitoring") + _run(12, 20, "monitoring", True, warn), 20.0)
    assert v.level == "OK" and v.monitored_s == pytest.approx(14.0, abs=1e-6)


def test_fault_from_the_reports_events() -> None:
    reps = _startup() + _run(6, 20, "monitoring")
    ev = SimpleNamespace(mode=1, quantity="natural_frequency", direction="down", onset_time_s=12.0,
                         alarm_time_s=12.8, clear_time_s=None, baseline=30.0, value=28.5)
    reps[128].events_opened = [ev]
    v = assess(reps, 20.0)
    assert v.level == "FAULT"
    assert "mode 1 natural frequency down -5.0 % since 12.00 s (still open at the end)" in v.text
    assert "14.0 s of 20.0 s" in v.text
    _partition_ok(v, 20.0)


def test_degraded_after_a_data_gap_states_where_and_why() -> None:
    """Monitoring 6-12 s, no samples 12-14 s, baseline window restarted (settling, learning) until 18 s."""
    gap = {"hold": True, "issues": ["data_gap", "repriming"],
           "reasons": ["data gap of 2 s (estimator re-primed) (recovering, hold-off until t=15.0 s)",
                       "estimator filters re-priming after a data break"]}
    reps = (_startup() + _run(6, 12, "monitoring") + _run(14, 16, "settling", True, gap) + _run(16, 18, "learning")
            + _run(18, 20, "monitoring"))
    v = assess(reps, 20.0)
    assert v.level == "DEGRADED"
    assert v.monitored_s == pytest.approx(8.0, abs=1e-6)
    bad = [b for b in v.blind_intervals if not b.startup]
    assert [(b.kind, round(b.start_s, 6), round(b.end_s, 6)) for b in bad] == [
        ("no_data", 12.0, 14.0), ("settling", 14.0, 16.0), ("learning", 16.0, 18.0)]
    assert "data gap of 2 s" in bad[1].reason and "recovering" not in bad[1].reason
    assert "8.0 s of 20.0 s" in v.text and "12.0–18.0 s" in v.text and "data gap of 2 s" in v.text
    assert not v.text.lower().startswith("no structural fault")
    _partition_ok(v, 20.0)
    # the same rules over the report's DiagnosisSeries (what report.html shows)
    series = rp.DiagnosisSeries.from_reports(reps, 1)
    v2 = rp.assess_series([], series, 20.0)
    assert (v2.level, v2.text) == (v.level, v.text)


def test_degraded_by_a_health_hold_while_monitoring() -> None:
    nan = {"hold": True, "issues": ["nonfinite"],
           "reasons": ["40 non-finite sensor samples skipped (recovering, hold-off until t=13.0 s)"]}
    v = assess(_startup() + _run(6, 10, "monitoring") + _run(10, 13, "monitoring", True, nan)
               + _run(13, 20, "monitoring"), 20.0)
    assert v.level == "DEGRADED" and v.monitored_s == pytest.approx(11.0, abs=1e-6)
    (hold,) = [b for b in v.blind_intervals if not b.startup]
    assert hold.kind == "hold" and (hold.start_s, hold.end_s) == pytest.approx((10.0, 13.0))
    assert hold.reason == "health hold: 40 non-finite sensor samples skipped"
    _partition_ok(v, 20.0)


def test_disruption_before_the_first_baseline_is_degraded() -> None:
    """A NaN burst during learning restarts the baseline window: the start-up is no longer undisturbed."""
    nan = {"hold": True, "issues": ["nonfinite"], "reasons": ["40 non-finite sensor samples skipped"]}
    reps = (_run(0, 2, "initializing", False, INIT) + _run(2, 4, "settling") + _run(4, 5, "learning")
            + _run(5, 7, "settling", True, nan) + _run(7, 9, "learning") + _run(9, 20, "monitoring"))
    v = assess(reps, 20.0)
    assert v.level == "DEGRADED" and v.monitored_s == pytest.approx(11.0, abs=1e-6)
    assert "baseline window restarted after: 40 non-finite" in v.text
    _partition_ok(v, 20.0)
    # the pipeline kept what was learned (its hold reason says so): the window was paused, not restarted
    paused = {**nan, "reasons": [*nan["reasons"], "fault tests held (blind) since t=5.0 s; baseline window paused "
                                 "(1.0 s learned, kept)"]}
    reps = (_run(0, 2, "initializing", False, INIT) + _run(2, 4, "settling") + _run(4, 5, "learning")
            + _run(5, 7, "settling", True, paused) + _run(7, 9, "learning") + _run(9, 20, "monitoring"))
    v = assess(reps, 20.0)
    assert "baseline window paused after: 40 non-finite" in v.text and "restarted" not in v.text


def test_never_monitored_is_degraded_not_ok() -> None:
    v = assess(_startup(t_mon=9.0), 9.0)
    assert v.level == "DEGRADED" and v.monitored_s == 0.0 and v.monitoring_start_s is None
    assert "never ran" in v.text and "could not be tested" in v.text
    _partition_ok(v, 9.0)


def test_no_estimate() -> None:
    v = assess(_run(0, 5, "initializing", False, INIT), 5.0)
    assert v.level == "NO ESTIMATE" and v.monitored_s == 0.0
    _partition_ok(v, 5.0)
    assert assess([], 3.0).level == "NO ESTIMATE"


def test_estimate_lost_after_monitoring_is_blind() -> None:
    lost = {"hold": True, "issues": ["reinitializing"], "reasons": ["estimator diverged: re-initializing"]}
    v = assess(_startup() + _run(6, 10, "monitoring") + _run(10, 20, "initializing", False, lost), 20.0)
    assert v.level == "DEGRADED" and v.monitored_s == pytest.approx(4.0, abs=1e-6)
    assert v.blind_intervals[-1].kind == "no_estimate" and "re-initializing" in v.blind_intervals[-1].reason
    _partition_ok(v, 20.0)


def test_advisory_issue_during_the_startup_hold_is_no_disruption() -> None:
    """The clean beam bag: a residual jump (advisory) appears while the start-up hold is still active."""
    both = {"hold": True, "issues": ["initializing", "residual_jump"],
            "reasons": ["initializing: collecting 2 s of valid data (recovering, hold-off until t=3.0 s)",
                        "residual variance jumped x3.18 over its healthy level"]}
    reps = (_run(0, 2, "initializing", False, INIT) + _run(2, 3, "settling", True, both) + _run(3, 4, "settling")
            + _run(4, 6, "learning") + _run(6, 20, "monitoring"))
    v = assess(reps, 20.0)
    assert v.level == "OK" and all(b.startup for b in v.blind_intervals)


def test_advisory_kinds_match_the_health_monitor() -> None:
    from additive_rsrivc_ros.core.diagnosis.faults import HealthMonitor
    from additive_rsrivc_ros.outputs.verdict import ADVISORY_ISSUES

    assert set(ADVISORY_ISSUES) == set(HealthMonitor.ADVISORY_KINDS)


def test_restart_without_a_hold_names_its_cause() -> None:
    """The fault monitor restarts the baseline window on a stress (residual jump) without a hold: still DEGRADED,
    and the reason shows the health report of that moment."""
    jump = {"hold": False, "issues": ["residual_jump"], "reasons": ["residual variance jumped x587"]}
    reps = _startup() + _run(6, 12, "settling", True, jump) + _run(12, 14, "learning") + _run(14, 20, "monitoring")
    v = assess(reps, 20.0)
    assert v.level == "DEGRADED" and v.monitored_s == pytest.approx(6.0, abs=1e-6)
    assert "6.0–14.0 s (baseline window restarted after: residual variance jumped x587)" in v.text


DELAY_FINDING = ("the configured input delay misfits the data: with input_delay_samples 3 instead of 2 the model's "
                 "output error on this window is 31 % of it")


def _flagged(state: str = "misfit") -> dict:
    """Health while the model-order check flags the model: WARN, no hold (core.adequacy.ModelOrderWatch.apply)."""
    return {"hold": False, "issues": [], "level": 1, "reasons": [DELAY_FINDING],
            "model_order": {"state": state, "message": DELAY_FINDING, "stage": "run"}}


@pytest.mark.parametrize("state", ["misfit", "too_low"])
def test_fault_tests_that_ran_against_a_flagged_model_are_degraded_not_ok(state: str) -> None:
    """The check only warns; but silent fault tests on a model that misfits the data (a wrong input delay missed
    the bundled bag's real fault) are no evidence of health: DEGRADED, naming the finding and the time."""
    reps = _startup() + _run(6, 15, "monitoring") + _run(15, 20, "monitoring", True, _flagged(state))
    v = assess(reps, 20.0)
    assert v.level == "DEGRADED"
    assert v.monitored_s == pytest.approx(14.0, abs=1e-6) and v.flagged_model_s == pytest.approx(5.0, abs=1e-6)
    assert "5.0 s of them against a model the model-order check flagged (from 15.0 s: the configured input" in v.text
    assert "a misfitting model can hide a fault" in v.text
    assert v.to_dict()["flagged_model_s"] == pytest.approx(5.0)
    _partition_ok(v, 20.0)   # a flag blinds nothing: the partition is unchanged


def test_a_flag_that_cleared_before_the_tests_ran_keeps_ok_and_is_named() -> None:
    """Flagged at the start, re-started from the data, adequate afterwards: the tests never ran on the flagged
    model, so OK; the text still says what happened."""
    adequate = {**HEALTHY, "model_order": {"state": "adequate", "message": "adequate"}}
    reps = (_run(0, 2, "initializing", False, INIT) + _run(2, 4, "settling", True, _flagged())
            + _run(4, 6, "learning", True, adequate) + _run(6, 20, "monitoring", True, adequate))
    v = assess(reps, 20.0)
    assert v.level == "OK" and v.flagged_model_s == 0.0
    assert "earlier, the model-order check flagged the model (from 2.0 s: the configured input delay" in v.text


def test_a_fault_found_on_a_flagged_model_stays_a_fault_and_says_so() -> None:
    reps = _startup() + _run(6, 20, "monitoring", True, _flagged())
    ev = SimpleNamespace(mode=2, quantity="natural_frequency", direction="down", onset_time_s=12.0,
                         alarm_time_s=12.8, clear_time_s=None, baseline=31.3, value=29.7)
    reps[128].events_opened = [ev]
    v = assess(reps, 20.0)
    assert v.level == "FAULT" and "against a model the model-order check flagged" in v.text


def test_the_series_view_of_the_reports_gives_the_same_flagged_verdict() -> None:
    """report.DiagnosisSeries keeps what the verdict reads (one rule over the reports and over the series)."""
    reps = _startup() + _run(6, 15, "monitoring") + _run(15, 20, "monitoring", True, _flagged())
    direct = assess(reps, 20.0)
    via_series = rp.assess_series([], rp.DiagnosisSeries.from_reports(reps, 1), 20.0)
    assert (via_series.level, via_series.text, via_series.flagged_model_s) == \
        (direct.level, direct.text, direct.flagged_model_s)


def test_monitoring_against_an_untrusted_baseline_is_not_ok() -> None:
    """CONTRACT: ``monitored_s`` counts the tests against a trusted baseline only. A baseline learned over too little
    of its window, or one the estimate moved within, gives DEGRADED with the baseline's note, never OK; an event
    raised against it still makes the record FAULT."""
    note = "the estimate moved during the 12.2 s baseline window (mode 2 natural_frequency -3.3 % from its first " \
           "half to its second); baseline untrusted"
    untrusted = {**HEALTHY, "baseline_trusted": False, "baseline_note": note, "reasons": [note], "level": 1}
    trusted = {**HEALTHY, "baseline_trusted": True, "baseline_note": ""}
    v = assess(_startup() + _run(6, 20, "monitoring", True, untrusted), 20.0)
    assert v.level == "DEGRADED" and v.monitored_s == 0.0
    assert v.blind_intervals[-1].kind == "untrusted" and "mode 2 natural_frequency -3.3 %" in v.text
    _partition_ok(v, 20.0)
    v = assess(_startup() + _run(6, 20, "monitoring", True, trusted), 20.0)
    assert v.level == "OK" and v.monitored_s == pytest.approx(14.0, abs=1e-6)
    ev = [{"mode": 2, "quantity": "natural_frequency", "direction": "down", "onset_time_s": 12.0,
           "alarm_time_s": 13.0, "clear_time_s": None, "baseline": 33.0, "value": 31.4}]
    assert assess(_startup() + _run(6, 20, "monitoring", True, untrusted), 20.0, ev).level == "FAULT"
