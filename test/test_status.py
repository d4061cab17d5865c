"""Status composition of the monitor's /diagnostics (additive_rsrivc_ros/outputs/status.py), without ROS."""

import subprocess
import sys

from additive_rsrivc_ros.core.diagnosis.faults import Level
from additive_rsrivc_ros.outputs.status import Finding, StatusRecord, estimator_summary, merge, mode_summary

OK, WARN, ERROR, STALE = Level.OK, Level.WARN, Level.ERROR, Level.STALE


def test_merge_takes_the_highest_level_and_joins_every_text_in_order():
    assert merge([]) == (OK, "")
    assert merge([Finding(OK, "a"), Finding(ERROR, "b"), Finding(WARN, "c")]) == (ERROR, "a; b; c")
    assert merge([Finding(WARN), Finding(OK, "x")]) == (WARN, "x")      # a level without a text adds no "; "
    assert merge([Finding(STALE), Finding(ERROR, "e")]) == (STALE, "e")  # STALE is the highest level
    level, _ = merge([Finding(WARN, "w")])
    assert isinstance(level, Level)


def test_estimator_is_its_health_when_nothing_else_holds():
    assert estimator_summary(Finding(OK), []) == (OK, "")
    assert estimator_summary(Finding(WARN), ["cond high", "anomaly"]) == (WARN, "cond high; anomaly")


def test_input_problems_and_internal_errors_raise_the_level_with_their_reasons_after_the_health():
    level, text = estimator_summary(Finding(OK), ["h"], recent_event=Finding(WARN, "input pause"),
                                    lasting=["rate"], internal_error="boom")
    assert (level, text) == (ERROR, "h; input pause; rate; internal error: boom")
    # an event that repeats a lasting reason raises the level without repeating its text
    assert estimator_summary(Finding(OK), [], recent_event=Finding(WARN), lasting=["rate"]) == (WARN, "rate")
    assert estimator_summary(Finding(OK), [], recent_event=Finding(WARN)) == (WARN, "")


def test_stale_estimator_yields_to_lasting_input_problems_but_not_to_a_passing_event():
    assert estimator_summary(Finding(STALE), [], lasting=["queue full"]) == (WARN, "queue full")
    assert estimator_summary(Finding(STALE), [], lasting=["q"], internal_error="x") == (ERROR, "q; internal error: x")
    assert estimator_summary(Finding(STALE), [], recent_event=Finding(WARN, "pause"))[0] == STALE
    assert estimator_summary(Finding(STALE), [], internal_error="x")[0] == STALE


def test_silence_is_stale_and_a_wrong_type_is_error_whatever_else_holds_with_their_texts_first():
    level, text = estimator_summary(Finding(ERROR), ["h"], lasting=["rate"], silent="no data on /y for more than 1 s")
    assert (level, text) == (STALE, "no data on /y for more than 1 s; h; rate")
    level, text = estimator_summary(Finding(STALE), ["h"], silent="no data on /y", wrong_types="wrong message type: t")
    assert (level, text) == (ERROR, "wrong message type: t; no data on /y; h")
    assert estimator_summary(Finding(OK), [], wrong_types="wrong message type: t") == (ERROR,
                                                                                      "wrong message type: t")


def test_mode_summary_precedence():
    fault = Finding(ERROR, "fault: natural_frequency down")
    assert mode_summary(fault, estimating=True) == (ERROR, "fault: natural_frequency down")
    assert mode_summary(fault, estimating=True, silent="no data on /y") == (STALE, "no data on /y")
    assert mode_summary(fault, estimating=False) == (STALE, "initializing")
    assert mode_summary(None, estimating=True, looking=False) == (STALE, "starting")
    assert mode_summary(None, estimating=True, looking=True) == (STALE, "initializing")
    assert mode_summary(None, estimating=False, silent="no data on /r") == (STALE, "no data on /r")


def test_status_record_keeps_the_values_in_order():
    rec = StatusRecord("n: estimator", WARN, "m", {"b": 1, "a": 2.0})
    assert list(rec.values) == ["b", "a"] and rec.level == WARN


def test_status_module_imports_no_ros():
    code = ("import sys; import additive_rsrivc_ros.outputs.status; "
            "bad = sorted(m for m in sys.modules if m.split('.')[0] in ('rclpy', 'diagnostic_msgs', 'std_msgs', "
            "'rcl_interfaces')); print(bad); sys.exit(1 if bad else 0)")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr
