"""The automatic start inside MonitorPipeline (no mode guesses; core/identification/autostart.py), on simulated
closed loops with
known modes (the plant, controller and excitation of test_frf / test_modefind).

Accuracy of the modes found: the modefind tests' tolerance (1 % in frequency, 15 % in damping). Once found, the
estimator must get the samples exactly as a pipeline started with the found modes as guesses would have: its
estimates are compared with such a pipeline's to rounding (rtol 1e-12; the same arithmetic gives bit-identical
numbers). Confidently-wrong cases: a window without excitation and a NaN burst in the window give no numbers, one
health line that says why, and a start on a later window.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from frf_cases import CONTROLLER, DELAY, FS, MODES

from additive_rsrivc_ros.config import MonitorConfig, validate_params
from additive_rsrivc_ros.core.diagnosis.faults import Level
from additive_rsrivc_ros.core.monitor.pipeline import MonitorPipeline, PipelineError
from additive_rsrivc_ros.sim.simulate import simulate_modes, square_wave, white_noise

PARAMS = {"loop_rate_hz": FS, "closed_loop": True, "controller.numerator": list(CONTROLLER.numerator),
          "controller.denominator": list(CONTROLLER.denominator), "input_delay_samples": DELAY,
          "modes.memory_s": [5.0], "init_duration_s": 5.0}
BLOCK = int(0.25 * FS)


def _cfg(**kw) -> MonitorConfig:
    return MonitorConfig.from_params(validate_params({**PARAMS, **kw}))


def _sim(seed: int, duration_s: float, flat_until_s: float = 0.0):
    """Closed loop of test_modefind: 0.5 Hz square-wave setpoint plus white dither; constant before ``flat_until_s``."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(duration_s * FS)) / FS
    r = square_wave(t, 0.5, 1.0) + white_noise(t.size, 0.05, rng)
    r[t < flat_until_s] = 0.3
    sim = simulate_modes(MODES, FS, r=r, controller=CONTROLLER, input_delay=DELAY,
                         noise=white_noise(t.size, 0.01, rng), rng=rng)
    return t, sim.r, sim.u, sim.y.copy()


def _run(cfg, t, r, u, y, start: int = 0):
    pipe = MonitorPipeline(cfg)
    reports = []
    for a in range(start, t.size, BLOCK):
        reports += pipe.push(t[a:a + BLOCK], r[a:a + BLOCK], u[a:a + BLOCK], y[a:a + BLOCK])
    return pipe, reports


def _check_found(pipe):
    found = pipe.search.found
    assert found is not None and pipe.K == len(MODES)
    for m, truth in zip(found.modal, MODES, strict=True):
        assert abs(m[0] / truth.natural_frequency_hz - 1.0) < 0.01
        assert abs(m[1] / truth.damping_ratio - 1.0) < 0.15
    return found


def _same_estimates(auto_reports, guess_reports, after_s: float, guess_start_s: float = 0.0) -> int:
    """Compare the estimates at the common report instants after ``after_s`` (the guess pipeline's times count from
    its first sample, at ``guess_start_s``); return how many."""
    guess = {round(rep.time_s + guess_start_s, 6): rep for rep in guess_reports if rep.estimating}
    n = 0
    for rep in auto_reports:
        t = round(rep.time_s, 6)
        if t >= after_s and t in guess:
            assert rep.estimating
            np.testing.assert_allclose(rep.modal, guess[t].modal, rtol=1e-12, atol=0.0)
            n += 1
    return n


@pytest.fixture(scope="module")
def clean():
    return _sim(11, 15.0)


def test_no_guesses_finds_the_modes_and_then_estimates_as_with_guesses(clean):
    t, r, u, y = clean
    cfg = _cfg()
    assert cfg.auto_modes
    pipe, reports = _run(cfg, t, r, u, y)
    found = _check_found(pipe)
    assert found.window_s == pytest.approx((0.0, 5.0))
    before = [rep for rep in reports if rep.K == 0]
    assert before and all(rep.time_s < 5.0 for rep in before)
    for rep in before:   # no number without a model: K = 0, nothing estimated, health says what happens
        assert not rep.estimating and rep.modal.shape == (0, 6) and rep.phase == "finding modes"
        assert rep.health["reasons"][0].startswith("starting: finding modes")
        assert rep.health["level"] == Level.STALE and rep.health["autostart"]["state"] == "finding"
    notices = [n for rep in reports for n in rep.notices]
    assert len(notices) == 1 and notices[0].startswith("no mode guesses: found 2 mode(s) on the first 5 s")
    assert all(rep.health["model_order"]["state"] in ("pending", "adequate") for rep in reports if rep.estimating)
    assert reports[-1].health["autostart"]["K"] == 2
    # the same estimator as a pipeline started with the found modes as guesses: same init window, same updates
    _, guess = _run(cfg.with_modes(found.modal, found.integrators), t, r, u, y)
    first_auto = next(rep.time_s for rep in reports if rep.estimating)
    first_guess = next(rep.time_s for rep in guess if rep.estimating)
    assert first_auto == pytest.approx(first_guess)
    assert _same_estimates(reports, guess, 0.0) == sum(rep.estimating for rep in guess) > 50


def test_found_modes_survive_a_saved_state_and_reset_finds_them_again(clean):
    t, r, u, y = clean
    cfg = _cfg()
    pipe, _ = _run(cfg, t[:8000], r, u, y)
    state = json.loads(json.dumps(pipe.get_state()))
    back = MonitorPipeline(cfg, state=state)          # the node restarting without guesses
    assert back.K == 2 and back.initialized and not back.finding_modes
    np.testing.assert_array_equal(back.modal(), pipe.modal())
    assert back.push(t[8000:8100], r[8000:8100], u[8000:8100], y[8000:8100]) is not None
    with pytest.raises(PipelineError, match="K=2"):   # a guess configuration of another K refuses it
        MonitorPipeline(cfg.with_modes(np.array([[5.0, 0.05, 1.0]])), state=state)
    pipe.reset()
    assert pipe.finding_modes and pipe.K == 0 and not pipe.initialized


def test_runtime_memory_before_the_modes_are_found_applies_to_them(clean):
    t, r, u, y = clean
    pipe = MonitorPipeline(_cfg())
    pipe.update_params({"modes.memory_s": [7.0], "faults.min_change.natural_frequency": 0.05})
    with pytest.raises(PipelineError):
        pipe.update_params({"modes.memory_s": [1e-4]})
    for a in range(0, 6000, BLOCK):
        pipe.push(t[a:a + BLOCK], r[a:a + BLOCK], u[a:a + BLOCK], y[a:a + BLOCK])
    assert pipe.K == 2 and pipe.memory_s.tolist() == [7.0, 7.0]
    assert pipe.faults.settings.min_change[0] == 0.05


def test_window_without_excitation_publishes_nothing_and_starts_when_excitation_begins():
    t, r, u, y = _sim(5, 15.0, flat_until_s=5.0)
    pipe, reports = _run(_cfg(), t, r, u, y)
    fail = next(rep for rep in reports if rep.notices)
    assert fail.time_s == pytest.approx(5.0, abs=0.11) and fail.K == 0 and not fail.estimating
    assert "no excitation: the reference is constant" in fail.notices[0]
    assert fail.health["level"] == Level.WARN and any("no modes found on t=0.0–5.0 s" in x
                                                      for x in fail.health["reasons"])
    assert all(rep.K == 0 and not rep.estimating for rep in reports if rep.time_s < 10.0 - 1e-9)
    found = _check_found(pipe)        # recovered on the next window, once the setpoint moves
    assert found.window_s == pytest.approx((5.0, 10.0)) and found.attempts == 2
    after = [rep for rep in reports if rep.time_s > 10.5]
    assert after and all(rep.estimating and rep.K == 2 for rep in after)
    assert not any("no modes found" in x for x in after[-1].health["reasons"])   # the failure line is gone


def test_nan_burst_in_the_window_is_a_retry_not_a_guess():
    t, r, u, y = _sim(7, 18.0)
    y[(t >= 1.0) & (t < 4.0)] = np.nan       # leaves 1 s of contiguous valid data in the first window
    pipe, reports = _run(_cfg(), t, r, u, y)
    notes = [n for rep in reports for n in rep.notices]
    assert "contiguous valid samples" in notes[0] and notes[1].startswith("no mode guesses: found 2 mode(s)")
    assert all(rep.K == 0 and np.all(~np.isfinite(rep.modal)) for rep in reports if rep.time_s < 10.0 - 1e-9)
    found = _check_found(pipe)
    assert found.window_s == pytest.approx((5.0, 10.0))
    assert reports[-1].health["nonfinite"] == 3000
    # from the window on, the estimator saw what a guess pipeline whose data began there sees
    _, guess = _run(pipe.cfg_given.with_modes(found.modal, found.integrators), t, r, u, y, start=int(5.0 * FS))
    assert _same_estimates(reports, guess, 10.0, guess_start_s=5.0) > 50


def test_guesses_without_a_valid_model_are_replaced_by_modes_from_the_data(clean):
    """Issue 12 item 4: log-spaced guesses (someone who knows nothing) give an initial model the controller does not
    stabilize; the start then finds the K modes in the same window instead, says so on health, and tracks the
    truth; a healthy plant raises no structural event on the way."""
    t, r, u, y = clean
    k = len(MODES)
    cfg = _cfg(**{"modes.natural_frequency_hz": list(np.geomspace(1.0, 1000.0, k + 2)[1:-1]),
                  "modes.damping_ratio": [0.1] * k, "modes.gain": [1.0] * k, "modes.memory_s": [5.0] * k})
    pipe, reports = _run(cfg, t, r, u, y)
    assert pipe.counters.invalid_models >= 1 and pipe.counters.data_starts == 1
    said = [why for rep in reports for why in rep.health["reasons"] if "mode guesses gave no valid model" in why]
    assert said, "the replacement of the guesses is not on health"
    assert not any(rep.events_opened for rep in reports)
    last = reports[-1]
    assert last.estimating
    for m, truth in zip(last.modal, MODES, strict=True):
        assert abs(m[0] / truth.natural_frequency_hz - 1.0) < 0.01
        assert abs(m[1] / truth.damping_ratio - 1.0) < 0.15


def test_a_wrong_start_is_flagged_by_the_model_check_and_restarted_from_the_data(monkeypatch):
    """Issue 12 item 4: a start that is wrong for the data is not reported as healthy. The first automatic start
    is forced to one mode (as a start cut from a running loop with a slow closed-loop pole found, measured on
    20 s at 4096 Hz: one or two modes of four): the 40 Hz mode is then unmodelled and biases the 5 Hz one. It
    misfits its own window, so it is flagged from its first estimate (health WARN, ``model_order`` stage
    ``start``); the model-order check on the first 4 memory lengths after the start names it (no structural event),
    the modes are found again on that window (K automatic: the true two), pass the same check, and the estimator
    starts over from them; at the end the estimates are the truth's and the check passes."""
    from additive_rsrivc_ros.core.identification import modefind

    calls: list = []
    orig = modefind.autostart_config

    def first_start_wrong(cfg, r, u, y, count=None, refit_tol=modefind.FINAL_TOL):
        calls.append(count)
        return orig(cfg, r, u, y, count=1 if len(calls) == 1 else count, refit_tol=refit_tol)

    monkeypatch.setattr(modefind, "autostart_config", first_start_wrong)
    t, r, u, y = _sim(11, 40.0)
    pipe, reports = _run(_cfg(), t, r, u, y)
    assert len(calls) == 2
    notices = [n for rep in reports for n in rep.notices]
    found = next(i for i, n in enumerate(notices) if n.startswith("model-order check on"))
    assert "model order too low" in notices[found] or "model misfits the data" in notices[found]
    line = notices[found + 1]
    assert line.startswith("restarted from the data") and "the 2 mode(s) found" in line and "starts over" in line
    i = next(k for k, rep in enumerate(reports) if line in rep.notices)
    before = [rep.modal.shape[0] for rep in reports[:i]]
    assert set(before) == {0, 1} and reports[i].modal.shape[0] == 2     # finding modes, then the wrong start
    # flagged from its first estimate: the start misfits its own window (adequacy.check_start)
    assert notices[0].startswith("no mode guesses: found 1 mode(s)")
    assert notices[1].startswith("model check of the automatic start on t=0.0–5.0 s: ")
    wrong = [rep for rep in reports[:i] if rep.estimating]
    assert wrong and all(rep.health_level >= Level.WARN and rep.health["model_order"]["stage"] == "start"
                         and rep.health["model_order"]["message"] in rep.health["reasons"] for rep in wrong)
    assert reports[i].health_level >= Level.WARN and any(x.startswith(line) for x in reports[i].health["reasons"])
    assert not any(rep.events_opened for rep in reports)
    _check_found(pipe)
    last = reports[-1]
    assert last.health["model_order"]["state"] == "adequate", last.health["model_order"]
    for m, truth in zip(last.modal, MODES, strict=True):
        assert abs(m[0] / truth.natural_frequency_hz - 1.0) < 0.01


@pytest.mark.parametrize("scale", [1.0, 1.0 + 8e-12, 1.0 + 11e-12])
def test_guesses_that_lead_to_a_wrong_optimum_are_never_reported_healthy(scale):
    """Guesses 5 and 5.5 Hz for the 5 Hz + 40 Hz loop. The initialization and the recursion may settle on the 5 Hz
    mode split in two (measured: 5.00 Hz zeta 0.034 and 4.85 Hz zeta 0.12 at 58 s), with the 40 Hz mode missing;
    whether they do depends on the machine's rounding (the split mode is a saddle the recursion may leave by
    diverging, or never reach). What must hold on every machine: no report publishes a wrong estimate (a mode more
    than 5 % off its true frequency, the modes matched in order, or a damping ratio of 1 or more) with health OK. On a
    Xeon of 2026-11, eb7cac6 (before the check of the initial model) reported wrong modes with health OK for 8 s
    (``scripts/study_wrong_optimum.py --tree DIR`` prints it). When the wrong optimum happens, the estimate's own
    misfit flags it (the check of the initial model on its own window, or the regular model-order check later), the
    K = 2 modes are found again on the window and the estimator starts over from them. At the end the estimates are
    the truth's, with no structural event. ``scale``: the guesses times 1 + a few 1e-12, other rounding paths (on a
    Xeon of 2026-11, 1 + 8e-12 and 1 + 11e-12 reach the truth without a flag, 1 is flagged at 5 s;
    ``scripts/study_wrong_optimum.py --perturb 12`` prints a table of such runs)."""
    t, r, u, y = _sim(11, 60.0)
    cfg = _cfg(**{"modes.natural_frequency_hz": [5.0 * scale, 5.5 * scale], "modes.damping_ratio": [0.1, 0.1],
                  "modes.gain": [1.0, 1.0], "modes.memory_s": [5.0, 5.0]})
    pipe, reports = _run(cfg, t, r, u, y)
    truth = np.sort([m.natural_frequency_hz for m in MODES])
    healthy_while_wrong = []
    for rep in reports:
        if not rep.estimating or int(rep.health["level"]) != int(Level.OK):
            continue
        f = np.sort(rep.modal[:, 0])
        if not np.all(np.isfinite(f)) or np.any(np.abs(f / truth - 1.0) > 0.05) or np.any(rep.modal[:, 1] >= 1.0):
            healthy_while_wrong.append(rep.time_s)
    assert not healthy_while_wrong, f"wrong estimates reported with health OK at {healthy_while_wrong[:5]} s"
    notices = [n for rep in reports for n in rep.notices]
    k = next((i for i, n in enumerate(notices)
              if n.startswith(("model-order check on", "model check of the initial model on"))), None)
    if k is not None:   # the wrong optimum happened on this rounding path: flagged, restarted from the data
        assert "misfits the data" in notices[k] and "wrong optimum" in notices[k]
        assert notices[k + 1].startswith("restarted from the data") and "the 2 mode(s) found" in notices[k + 1]
    assert not any(rep.events_opened for rep in reports)
    last = reports[-1]
    assert last.health["model_order"]["state"] == "adequate"
    for m, truth_mode in zip(last.modal, MODES, strict=True):
        assert abs(m[0] / truth_mode.natural_frequency_hz - 1.0) < 0.01
        assert abs(m[1] / truth_mode.damping_ratio - 1.0) < 0.15


def test_a_restart_that_fails_leaves_the_model_flagged_not_crashed(monkeypatch):
    """The forced one-mode start of the test above, and the search on the check's window raises: the run goes on
    with the one-mode model, its flag on health (WARN) with the check's reason, and a notice says why the restart
    failed; nothing crashes and nothing is reported as healthy."""
    from additive_rsrivc_ros.core.identification import modefind

    calls: list = []
    orig = modefind.autostart_config

    def second_search_breaks(cfg, r, u, y, count=None, refit_tol=modefind.FINAL_TOL):
        calls.append(count)
        if len(calls) > 1:
            raise RuntimeError("simulated failure\nsecond line")
        return orig(cfg, r, u, y, count=1, refit_tol=refit_tol)

    monkeypatch.setattr(modefind, "autostart_config", second_search_breaks)
    t, r, u, y = _sim(11, 40.0)
    pipe, reports = _run(_cfg(), t, r, u, y)
    assert len(calls) == 2 and pipe.K == 1
    notices = [n for rep in reports for n in rep.notices]
    assert "restart from the data failed (RuntimeError: simulated failure); the model stays flagged" in notices
    last = reports[-1]
    assert last.health["model_order"]["state"] in ("too_low", "misfit") and last.health_level >= Level.WARN
    assert last.health["model_order"]["message"] in last.health["reasons"]


@pytest.mark.parametrize("burst", [True, False])
def test_a_failed_window_with_invalid_samples_keeps_its_length(monkeypatch, burst):
    """A search that fails on an excited window grows the next window (a mode the window was too short for), unless
    the window held invalid samples: then the gaps may be why, and the next window keeps the length (on the bundled
    bag with 40 NaN outputs at 2 s the modes were found at 8 s instead of 12 s). The first search is made to fail."""
    from additive_rsrivc_ros.core.identification import modefind

    calls: list = []
    orig = modefind.autostart_config

    def first_search_fails(cfg, r, u, y, count=None, refit_tol=modefind.FINAL_TOL):
        calls.append(int(np.count_nonzero(~np.isfinite(y))))
        if len(calls) == 1:
            raise ValueError("no model order could be fitted (simulated)")
        return orig(cfg, r, u, y, count=count, refit_tol=refit_tol)

    monkeypatch.setattr(modefind, "autostart_config", first_search_fails)
    t, r, u, y = _sim(7, 22.0)
    if burst:
        y[(t >= 3.0) & (t < 3.1)] = np.nan     # 3 s of contiguous valid data before it: an excited window
    pipe, reports = _run(_cfg(), t, r, u, y)
    notes = [n for rep in reports for n in rep.notices]
    assert len(calls) == 2 and (calls[0] > 0) == burst and calls[1] == 0
    found = _check_found(pipe)
    if burst:
        assert "invalid samples in the window: the next one keeps its length" in notes[0]
        assert "retrying on the next 5 s" in notes[0] and found.window_s == pytest.approx((5.0, 10.0))
    else:
        assert "keeps its length" not in notes[0]
        assert "retrying on the next 10 s" in notes[0] and found.window_s == pytest.approx((5.0, 15.0))
