"""Model-order check (core/identification/adequacy.py, issue 12 item 4): a model with a mode too few that biases what
we report is
flagged on health with the unmodelled resonance; a correct or deliberately reduced model is not."""

from __future__ import annotations

import numpy as np
import pytest

from additive_rsrivc_ros.config import MonitorConfig, load_params_file
from additive_rsrivc_ros.core.diagnosis.faults import Level
from additive_rsrivc_ros.core.identification.adequacy import ModelOrderCheck
from additive_rsrivc_ros.core.monitor.pipeline import MonitorPipeline
from additive_rsrivc_ros.sim.plants import BEAM_MODES, PAPER_MODES
from additive_rsrivc_ros.sim.scenarios import build, config_dir
from additive_rsrivc_ros.sim.simulate import simulate_modes, sum_of_sines, time_vector, white_noise

BEAM_F = [m.natural_frequency_hz for m in BEAM_MODES]


def _run(cfg: MonitorConfig, t, r, u, y, chunk: int = 4096) -> list:
    pipe = MonitorPipeline(cfg)
    reports = []
    for a in range(0, t.size, chunk):
        reports += pipe.push(t[a:a + chunk], None if r is None else r[a:a + chunk], u[a:a + chunk], y[a:a + chunk])
    return reports + pipe.flush()


def _beam_config(k: int) -> MonitorConfig:
    p = dict(load_params_file(config_dir() / "beam_healthy.yaml"))
    p.update({key: list(v)[:k] for key, v in p.items() if key.startswith("modes.") and isinstance(v, list)})
    return MonitorConfig.from_params(p)


def test_beam_with_one_mode_too_few_is_flagged_at_the_unmodelled_frequency():
    """Only the 3.25 Hz mode modelled: the 33 Hz mode biases its frequency by ~2 % (more than half the 2 % minimum
    relevant change): health WARN naming the unmodelled resonance, no structural event."""
    data = build("beam_healthy", duration_s=15.0, seed=1)
    cfg = _beam_config(1)
    reports = _run(cfg, data.t, data.r, data.u, data.y)
    last = reports[-1]
    order = last.health["model_order"]
    assert order["state"] == "too_low", order
    moving = [e for e in order["extra_modes"] if e["moves_modelled_modes"]]
    assert len(moving) == 1
    # the K + 1 fit is the beam's 2-mode model: its extra mode is the true 33 Hz mode (modes 3-4 at 172/183 Hz bias
    # it by ~0.01 %, as they bias the bundled 2-mode estimate)
    assert moving[0]["natural_frequency_hz"] == pytest.approx(BEAM_F[1], rel=2e-3)
    f1_without = last.modal[0, 0]
    assert abs(f1_without / BEAM_F[0] - 1.0) > 0.01          # the reported estimate is biased ...
    assert moving[0]["relative_change"][0][0] == pytest.approx(BEAM_F[0] / f1_without - 1.0, abs=2e-3)  # ... by this
    assert last.health_level >= Level.WARN
    line = next(x for x in last.health["reasons"] if x.startswith("model order too low"))
    assert f"near {moving[0]['natural_frequency_hz']:.4g} Hz" in line and "mode 1 natural frequency" in line
    assert not any(rep.events_opened for rep in reports)
    assert any(n.startswith("model-order check") for rep in reports for n in rep.notices)
    flagged = [rep.time_s for rep in reports if rep.health["model_order"]["state"] == "too_low"]
    window = 4.0 * cfg.modes[0].memory_s
    assert flagged[0] == pytest.approx(cfg.init_duration_s + window, abs=0.2)   # right after its window


def test_correctly_modelled_beam_is_not_flagged():
    """The beam's first two modes as the whole plant, both modelled: nothing is missing."""
    cfg = _beam_config(2)
    rng = np.random.default_rng(2)
    t = time_vector(cfg.loop_rate_hz, 15.0)
    r = 0.1 * np.sign(np.sin(2 * np.pi * 2.0 * t) + 1e-12)
    sim = simulate_modes(BEAM_MODES[:2], cfg.loop_rate_hz, r=r, controller=cfg.controller,
                         input_delay=cfg.input_delay_samples, noise=white_noise(t.size, 3e-4, rng), rng=rng)
    reports = _run(cfg, t, r, sim.u, sim.y)
    order = reports[-1].health["model_order"]
    assert order["state"] == "adequate", order
    assert not any(x.startswith("model order") for x in reports[-1].health["reasons"])


def test_correctly_modelled_paper_plant_is_not_flagged():
    """000 §5 plant (3 modes at 20 Hz, closed loop, white reference), all three modelled."""
    p = load_params_file(config_dir() / "paper_example.yaml")
    p.update({"modes.memory_s": [20.0] * 3, "init_duration_s": 30.0})
    cfg = MonitorConfig.from_params(p)
    rng = np.random.default_rng(4)
    t = time_vector(cfg.loop_rate_hz, 120.0)
    r = sum_of_sines(t, [3.0, 1.0, 1.0, 1.0], [0.005, 2.0, 5.0, 17.5]) + white_noise(t.size, 1.0, rng)
    sim = simulate_modes(PAPER_MODES, cfg.loop_rate_hz, r=r, controller=cfg.controller,
                         noise=white_noise(t.size, 0.1, rng), rng=rng)
    reports = _run(cfg, t, r, sim.u, sim.y, chunk=200)
    order = reports[-1].health["model_order"]
    assert order["state"] == "adequate", order
    assert order["n_bins"] > 0


def test_window_restarts_after_a_break_and_zero_disables():
    chk = ModelOrderCheck(100.0, 1.0, 0.25)
    ones = np.ones(50)
    ok = np.ones(50, dtype=bool)
    assert not chk.add(ones, ones, ones, ok, 0.49, longest_memory_s=2.0)     # samples 0..49 of a 2 s window
    assert chk.n == 50
    assert not chk.add(ones, ones, ones, ok, 0.99, longest_memory_s=2.0)     # contiguous: 100
    assert chk.n == 100
    assert not chk.add(ones, ones, ones, ok, 5.0, longest_memory_s=2.0)      # a gap: the window starts again
    assert chk.n == 50 and chk.t_start_s == pytest.approx(4.51)
    health = {"reasons": [], "level": 0, "ok": True}
    ModelOrderCheck(100.0, 0.0, 0.25).apply(health, Level.WARN)
    assert health["model_order"] == {"state": "off"} and health["level"] == 0


def test_identify_reports_a_model_order_too_low(tmp_path, capsys):
    """rsrivc_identify runs the same check on its fit: the bundled beam_fault bag (mode 2 at 32.97 Hz, 31.32 Hz after
    the 5 % fault at 20 s) with only mode 1 modelled."""
    import json
    from pathlib import Path

    import yaml

    from additive_rsrivc_ros.cli import identify

    repo = Path(__file__).resolve().parents[1]
    doc = yaml.safe_load((repo / "config" / "beam_fault.yaml").read_text())
    modes = doc["/**/additive_rsrivc_monitor"]["ros__parameters"]["modes"]
    for key in modes:
        modes[key] = modes[key][:1]
    params = tmp_path / "k1.yaml"
    params.write_text(yaml.safe_dump(doc))
    out = tmp_path / "id.json"
    assert identify.main([str(repo / "bags" / "beam_fault"), "--params-file", str(params), "--out", str(out)]) == 0
    order = json.loads(out.read_text())["model_order"]
    assert order["state"] == "too_low", order
    extra = next(e for e in order["extra_modes"] if e["moves_modelled_modes"])
    assert 0.99 * BEAM_F[1] * 0.95 < extra["natural_frequency_hz"] < 1.01 * BEAM_F[1]
    assert "model order: model order too low" in capsys.readouterr().out


def _square_wave_loop(modes, rate: float, delay: int, ctrl, seed: int):
    """20 s of the loop under a square wave at a fifth of the lowest mode with 5 % dither, output noise 1 % of the
    output's std (the validate_autostart.py generator's excitation)."""
    from additive_rsrivc_ros.sim.simulate import square_wave

    rng = np.random.default_rng(seed)
    t = time_vector(rate, 20.0)
    r = square_wave(t, min(m.natural_frequency_hz for m in modes) / 5.0, 1.0) + white_noise(t.size, 0.05, rng)
    clean = simulate_modes(modes, rate, r=r, controller=ctrl, input_delay=delay)
    return simulate_modes(modes, rate, r=r, controller=ctrl, input_delay=delay,
                          noise=white_noise(t.size, 0.01 * float(np.std(clean.y)), rng), rng=rng)


def _four_mode_loop():
    """A closed-loop plant of the ``validate_autostart`` generator's kind (4 modes, 1 kHz loop, PI, square wave):
    ``(rate, delay, controller, simulation, true thetas, structures)``."""
    from additive_rsrivc_ros.core.controller import DiscreteController
    from additive_rsrivc_ros.sim.simulate import PlantMode

    modes = [PlantMode(6.7694, 0.04721, 0.6821), PlantMode(29.901, 0.09390, 0.4242),
             PlantMode(41.402, 0.05211, 0.6648), PlantMode(95.315, 0.006486, 0.5665)]
    rate, delay = 1000.0, 2
    ctrl = DiscreteController((0.007048548526041672, -0.007018695704172541), (1.0, -1.0))
    sim = _square_wave_loop(modes, rate, delay, ctrl, 14)
    thetas = [np.array([2 * m.damping_ratio / (2 * np.pi * m.natural_frequency_hz),
                        1 / (2 * np.pi * m.natural_frequency_hz) ** 2, m.gain]) for m in modes]
    return rate, delay, ctrl, sim, thetas, [m.structure for m in modes]


def test_a_model_that_misfits_the_data_without_a_named_cause_is_flagged():
    """A closed-loop plant of the ``validate_autostart`` generator's kind (4 modes, 1 kHz loop, PI, square wave): the
    true model misfits no more bins than chance allows (Bonferroni, 1 %: at most a few), so ``adequate``. With its
    lightly damped 95 Hz mode (zeta 0.0065) left out, the other three cannot cover it and about half the bins, from
    9 Hz up, misfit, but no residual peak stands clear of the modelled modes to be tried as an extra one (measured
    with 3 noise seeds: 158-179 of 360-370 bins): before, that was ``adequate`` ("N of M FRF bins misfit, no
    unmodelled resonance found there"); now ``misfit``, flagged for health. (Leaving out any other mode, the refit
    finds the true modes but 29.9 Hz and the check names it: ``too_low``.)"""
    from additive_rsrivc_ros.core.identification.adequacy import MISFIT_FRACTION, check_model_order
    rate, delay, ctrl, sim, thetas, structures = _four_mode_loop()
    kw = dict(r=sim.r, controller=ctrl, input_delay=delay)
    right = check_model_order(thetas, structures, sim.u, sim.y, rate, **kw)
    assert right.state == "adequate" and right.n_misfit <= 5 and not right.flagged, right.to_dict()
    wrong = check_model_order(thetas[:3], structures[:3], sim.u, sim.y, rate, **kw)
    assert wrong.state == "misfit" and wrong.flagged, wrong.to_dict()
    assert wrong.n_misfit > MISFIT_FRACTION * wrong.n_bins and not any(e.real for e in wrong.extras)
    assert wrong.message.startswith("model misfits the data") and "not a fault" in wrong.message
    health = {"reasons": [], "level": 0, "ok": True}
    chk = ModelOrderCheck(rate, 1.0, 0.25)
    chk.result = wrong
    chk.apply(health, Level.WARN)
    assert health["level"] == Level.WARN and not health["ok"] and health["model_order"]["state"] == "misfit"
    assert health["reasons"] == [wrong.message]


def test_a_band_the_model_misses_is_flagged_though_few_bins_misfit():
    """validate_autostart.py --seed 1, plant 21 (1 kHz, PI, square wave at 0.67 Hz): the automatic start fitted the
    well-damped 3.3 Hz and 11.4 Hz modes as one 11.8 Hz lump with zeta 0.59 (and lost the weak 7.6 Hz one). That model
    misfits only about 8 % of the bins, under the 15 % rule, so it was ``adequate``; but the misfit bins lie in one
    band, 22 in a row, where right models misfit at most a few in a row (MISFIT_RUN_BINS). Now ``misfit``, named with
    its band; the true model stays ``adequate`` with a short longest run."""
    from additive_rsrivc_ros.core.controller import DiscreteController
    from additive_rsrivc_ros.core.identification.adequacy import MISFIT_FRACTION, MISFIT_RUN_BINS, check_model_order
    from additive_rsrivc_ros.core.model import theta_from_modal
    from additive_rsrivc_ros.sim.simulate import PlantMode

    modes = [PlantMode(3.3362, 0.17338, 0.65620), PlantMode(7.5615, 0.0058796, 0.25980),
             PlantMode(11.412, 0.20776, 0.64469), PlantMode(102.385, 0.015090, 0.73919)]
    rate, delay = 1000.0, 1
    ctrl = DiscreteController((0.012488184106702969, -0.012462061431688824), (1.0, -1.0))
    sim = _square_wave_loop(modes, rate, delay, ctrl, 21)
    kw = dict(r=sim.r, controller=ctrl, input_delay=delay)
    right = check_model_order([theta_from_modal(*m.modal) for m in modes], [m.structure for m in modes], sim.u,
                              sim.y, rate, **kw)
    assert right.state == "adequate" and right.misfit_run[0] < MISFIT_RUN_BINS / 2, right.to_dict()
    lump = [theta_from_modal(102.3852, 0.015, 0.7377), theta_from_modal(11.8213, 0.5878, 1.5983)]
    wrong = check_model_order(lump, [modes[0].structure] * 2, sim.u, sim.y, rate, **kw)
    assert wrong.state == "misfit" and wrong.flagged, wrong.to_dict()
    assert wrong.n_misfit < MISFIT_FRACTION * wrong.n_bins and wrong.misfit_run[0] >= MISFIT_RUN_BINS
    assert "in a row" in wrong.message and "not a fault" in wrong.message
    assert wrong.to_dict()["misfit_run"]["bins"] == wrong.misfit_run[0]


def _beam_two_modes(seconds: float, seed: int):
    """The beam's first two modes as the whole plant (true input delay 4 samples at 4096 Hz), square-wave setpoint."""
    cfg = _beam_config(2)
    rng = np.random.default_rng(seed)
    t = time_vector(cfg.loop_rate_hz, seconds)
    r = 0.1 * np.sign(np.sin(2 * np.pi * 2.0 * t) + 1e-12)
    sim = simulate_modes(BEAM_MODES[:2], cfg.loop_rate_hz, r=r, controller=cfg.controller,
                         input_delay=cfg.input_delay_samples, noise=white_noise(t.size, 3e-4, rng), rng=rng)
    return cfg, t, r, sim


@pytest.mark.parametrize(("configured", "better"), [(4, None), (2, 3), (7, 6)])
def test_the_configured_input_delay_is_checked_against_one_sample_more_and_fewer(configured, better):
    """Step 0: the true delay (4 samples) passes, both neighbours fit worse; a wrong one is flagged (``misfit``) with
    the neighbour towards the truth, and the misfit is not read as unmodelled resonances."""
    from additive_rsrivc_ros.core.identification.adequacy import DELAY_ERROR_RATIO, check_model_order

    cfg, t, r, sim = _beam_two_modes(10.0, seed=3)
    assert cfg.input_delay_samples == 4
    thetas = [m.theta0() for m in cfg.modes]
    res = check_model_order(thetas, cfg.structures, sim.u, sim.y, cfg.loop_rate_hz, r=r, controller=cfg.controller,
                            input_delay=configured)
    d = res.delay
    assert d is not None and d.configured == configured and d.better == better, res.to_dict()
    if better is None:
        assert res.state == "adequate", res.message
        assert set(d.ratios) == {3, 5} and min(d.ratios.values()) > 1.0 / DELAY_ERROR_RATIO   # both clearly worse
    else:
        assert res.state == "misfit" and res.extras == []
        assert f"input_delay_samples {better} instead of {configured}" in res.message
        assert d.error_ratio < DELAY_ERROR_RATIO
        assert res.to_dict()["input_delay"]["better"] == better


def test_a_wrong_input_delay_in_the_pipeline_is_on_health_without_events_or_a_restart():
    cfg, t, r, sim = _beam_two_modes(15.0, seed=4)
    p = dict(load_params_file(config_dir() / "beam_healthy.yaml"))
    p.update({key: list(v)[:2] for key, v in p.items() if key.startswith("modes.") and isinstance(v, list)})
    p["input_delay_samples"] = 2
    reports = _run(MonitorConfig.from_params(p), t, r, sim.u, sim.y)
    last = reports[-1]
    assert last.health["model_order"]["state"] == "misfit"
    assert last.health["model_order"]["input_delay"]["better"] == 3
    assert any("input delay" in x for x in last.health["reasons"]) and last.health_level >= Level.WARN
    assert not any(rep.events_opened for rep in reports)
    assert not any("restart from the data" in n for rep in reports for n in rep.notices)
    # the offline verdict does not call the silent fault tests on that model healthy (verdict.assess)
    from additive_rsrivc_ros.outputs.verdict import assess

    v = assess(reports, float(t[-1]))
    assert v.level == "DEGRADED" and "input_delay_samples 3 instead of 2" in v.text, v.line


def test_a_refit_that_misfits_does_not_flag_an_estimate_that_fits():
    """A correctly configured plant (2.7, 4.8, 13.5 and 818 Hz at 4096 Hz, PI loop, square wave plus dither) checked
    at its true modes on 15 s: the check's K-mode refit does not converge there and misfits 13-41 bins in a row at
    21-42 Hz (3 of 4 noise seeds), while the true modes fit the FRF (1 bin). That is the refit's failure: not flagged
    (it was 'model misfits the data' on a healthy plant). An estimate that misfits a band itself stays flagged."""
    from additive_rsrivc_ros.core.controller import DiscreteController
    from additive_rsrivc_ros.core.identification.adequacy import (
        MISFIT_RUN_BINS,
        OrderCheckResult,
        _verdict,
        check_model_order,
    )
    from additive_rsrivc_ros.core.model import theta_from_modal
    from additive_rsrivc_ros.sim.simulate import PlantMode, square_wave

    modes = [PlantMode(2.67045, 0.0808210, 0.311636), PlantMode(4.807873, 0.0118755, 0.686644),
             PlantMode(13.526855, 0.00523806, 0.343023), PlantMode(817.58223, 0.0701114, 0.305418)]
    rate = 4096.0
    ctrl = DiscreteController((0.009295074149591206, -0.009291268057102354), (1.0, -1.0))
    rng = np.random.default_rng(1)
    t = time_vector(rate, 25.0)
    r = square_wave(t, 0.53409, 1.0) + white_noise(t.size, 0.05, rng)
    clean = simulate_modes(modes, rate, r=r, controller=ctrl)
    noise = white_noise(t.size, 0.01 * float(np.std(clean.y)), rng)
    sim = simulate_modes(modes, rate, r=r, controller=ctrl, noise=noise, rng=rng)
    a = int(10 * rate)
    thetas = [theta_from_modal(*m.modal[:3]) for m in modes]
    res = check_model_order(thetas, [m.structure for m in modes], sim.u[a:], sim.y[a:], rate, r=r[a:],
                            controller=ctrl)
    assert res.misfit_run[0] >= MISFIT_RUN_BINS             # the refit failed (else this test would not test it)
    assert res.misfit_run_estimate < 3 and res.n_misfit_estimate < 3
    assert res.state == "adequate" and "refit" in res.message, res.message
    # the same numbers with the estimate misfitting a band itself: flagged
    bad = OrderCheckResult("adequate", "", n_bins=1600, n_misfit=59, threshold=12.0, misfit_run=(19, 26.0, 35.0),
                           n_misfit_estimate=20, misfit_run_estimate=15)
    assert _verdict(bad, np.array([0.005, 0.05, 0.025]))[0] == "misfit"


def test_the_initial_model_is_screened_on_its_own_window():
    """``check_initial_model`` (every initialization from guesses or after a divergence): the true model of the
    4-mode plant above on a 5 s window of its data passes the screen (None, no check run); with its 95 Hz mode left
    out it is flagged (``misfit``); NaN outputs are left out (the longest finite stretch is judged); a window whose
    longest finite stretch is under 2 s is not judged (None, never a flag from too little data)."""
    from additive_rsrivc_ros.core.identification.adequacy import check_initial_model
    rate, delay, ctrl, sim, thetas, structures = _four_mode_loop()
    w = slice(int(10 * rate), int(15 * rate))
    r, u, y = sim.r[w], sim.u[w], sim.y[w].copy()
    kw = dict(controller=ctrl, input_delay=delay)
    assert check_initial_model(thetas, structures, r, u, y, rate, **kw) is None
    wrong = check_initial_model(thetas[:3], structures[:3], r, u, y, rate, **kw)
    assert wrong is not None and wrong.flagged and wrong.state == "misfit", wrong
    y[: int(1.5 * rate)] = np.nan                                  # 3.5 s finite: still judged, on them
    assert check_initial_model(thetas[:3], structures[:3], r, u, y, rate, **kw).flagged
    y[int(1.5 * rate): int(3.2 * rate): 200] = np.nan              # no finite stretch of 2 s left
    assert check_initial_model(thetas[:3], structures[:3], r, u, y, rate, **kw) is None


def test_a_candidate_that_a_found_resonance_explains_is_not_refitted(monkeypatch):
    """Step 3: the beam's two modes modelled, its 172 and 183 Hz modes not. The residual FRF also peaks on the skirt
    of the 172 Hz resonance (a candidate near 120-140 Hz, no mode of the plant); once the 172 Hz mode is found, its
    K + 1 model fits the data there and that candidate is not refitted. Paired with every candidate refitted: the same
    state, message and real extra modes (the skipped refit only wandered back onto 172 Hz), one refit more."""
    from additive_rsrivc_ros.core.identification import adequacy

    cfg = _beam_config(2)
    data = build("beam_healthy", duration_s=12.0, seed=1)
    s = int(2.0 * cfg.loop_rate_hz)                          # a window cut from the running loop
    args = ([m.theta0() for m in cfg.modes], cfg.structures, data.u[s:], data.y[s:], cfg.loop_rate_hz)
    kw = {"r": data.r[s:], "controller": cfg.controller, "input_delay": cfg.input_delay_samples}
    refits: list[float] = []
    extra_mode = adequacy._extra_mode

    def counted(cand, *a, **k):
        refits.append(cand.natural_frequency_hz)
        return extra_mode(cand, *a, **k)

    monkeypatch.setattr(adequacy, "_extra_mode", counted)
    res = adequacy.check_model_order(*args, **kw)
    n_refits = len(refits)
    monkeypatch.setattr(adequacy, "_explained", lambda *a: False)
    refits.clear()
    every = adequacy.check_model_order(*args, **kw)

    real = sorted(e.modal[0] for e in res.extras if e.real)
    assert real == pytest.approx(sorted(BEAM_F[2:]), rel=5e-3)          # the true unmodelled modes, once each
    assert res.explained_hz, res.to_dict()
    for f in res.explained_hz:                                          # a skirt, not a resonance of the plant
        assert min(abs(f - g) for g in BEAM_F) > 10.0
    assert res.to_dict()["candidates_explained_hz"] == res.explained_hz
    assert (res.state, res.message) == (every.state, every.message) == ("adequate", res.message)
    assert real == pytest.approx(sorted(e.modal[0] for e in every.extras if e.real), rel=1e-12)
    assert every.explained_hz == [] and len(refits) == n_refits + len(res.explained_hz)
