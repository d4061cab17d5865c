"""MonitorPipeline end to end on the simulated 000 §5 plant (20 Hz, closed loop, dithered reference), known truth."""

from __future__ import annotations

import json

import numpy as np
import pytest

from additive_rsrivc_ros.config import MonitorConfig, load_params_file
from additive_rsrivc_ros.core.monitor.pipeline import MonitorPipeline, PipelineError
from additive_rsrivc_ros.sim.plants import PAPER_MODES
from additive_rsrivc_ros.sim.scenarios import build, config_dir
from additive_rsrivc_ros.sim.simulate import simulate_modes, sum_of_sines, time_vector, white_noise

MEMORY = 20.0          # s; lambda = 1 - 1/(20 * 20)


def _config(**extra) -> MonitorConfig:
    p = load_params_file(config_dir() / "paper_example.yaml")
    p.update({"modes.memory_s": [MEMORY] * 3, "init_duration_s": 30.0, **extra})
    return MonitorConfig.from_params(p)


def _simulate(duration: float, changes=(), seed: int = 3):
    cfg = _config()
    rng = np.random.default_rng(seed)
    t = time_vector(cfg.loop_rate_hz, duration)
    # the paper's four sines excite each mode at one line only (NOTES: frequency and gain of a mode are then
    # not separable); a white reference as in 001 §5.2 makes the truth identifiable
    r = sum_of_sines(t, [3.0, 1.0, 1.0, 1.0], [0.005, 2.0, 5.0, 17.5]) + white_noise(t.size, 1.0, rng)
    sim = simulate_modes(PAPER_MODES, cfg.loop_rate_hz, changes=list(changes), r=r, controller=cfg.controller,
                         noise=white_noise(t.size, 0.1, rng), rng=rng)
    return sim


@pytest.fixture(scope="module")
def beam_fault_run():
    """000 §6 beam at 4096 Hz (K = 2 of 4 plant modes), mode 2 frequency -5 % at 30 s (issue 7 target)."""
    data = build("beam_fault", duration_s=36.0, seed=0, fault_time_s=30.0)
    pipe = MonitorPipeline(data.config)
    n = int(data.config.loop_rate_hz / 10)
    reports = []
    for k in range(0, data.t.size, n):       # 0.1 s blocks, as the node feeds them
        reports += pipe.push(data.t[k:k + n], data.r[k:k + n], data.u[k:k + n], data.y[k:k + n])
    reports += pipe.flush()      # the end of the record: the aligner's held-back samples
    return data, pipe, reports


def test_beam_frequency_fault_detected_isolated_and_reported(beam_fault_run):
    data, pipe, reports = beam_fault_run
    memory = data.config.modes[1].memory_s
    times = np.array([r.time_s for r in reports])
    assert np.allclose(np.diff(times), 0.1)                      # publish_rate_hz = 10
    assert not reports[0].estimating and reports[-1].estimating
    assert reports[-1].phase == "monitoring"
    opened = [e for r in reports for e in r.events_opened]
    assert [(e.mode, e.quantity, e.direction) for e in opened] == [(2, "natural_frequency", "down")]
    ev = opened[0]
    assert 30.0 < ev.alarm_time_s <= 30.0 + 3 * memory            # within 3 memory lengths
    assert abs(ev.onset_time_s - 30.0) <= memory
    truth_before, truth_after = data.truth[1, 0, 0], data.truth[1, -1, 0]
    # the baseline is the healthy frequency within the model error of the unmodelled modes (1 %)
    assert ev.baseline == pytest.approx(truth_before, rel=0.01)
    assert ev.value == pytest.approx(truth_after, rel=0.02)
    last = reports[-1]
    assert last.flags.tolist() == [[False] * 3, [True, False, False]]
    assert last.levels[1, 0] == 2 and last.mode_levels.tolist()[0] == 0
    d = last.mode_dict(1)
    for key in ("natural_frequency_hz", "damping_ratio", "gain", "natural_frequency_hz_std", "damping_ratio_std",
                "gain_std", "baseline_natural_frequency_hz", "baseline_damping_ratio", "baseline_gain",
                "fault_natural_frequency", "fault_damping", "fault_gain"):
        assert key in d
    assert d["fault_natural_frequency"] is True
    json.dumps(last.to_dict())                                   # serializable for summary.json
    assert pipe.counters.samples_processed == data.t.size and pipe.counters.samples_dropped == 0


@pytest.fixture(scope="module")
def healthy_sim():
    return _simulate(450.0)


def test_chunking_and_bad_stamps_do_not_change_the_estimate():
    sim = _simulate(120.0)
    ref = MonitorPipeline(_config())
    rep_ref = ref.push(sim.t, sim.r, sim.u, sim.y)
    # the same samples in odd chunks, with duplicate and out-of-order stamps mixed in
    rng = np.random.default_rng(0)
    t, r, u, y = (list(v) for v in (sim.t, sim.r, sim.u, sim.y))
    for k in sorted(rng.choice(np.arange(5, sim.t.size - 5), 40, replace=False), reverse=True):
        j = k - int(rng.integers(0, 3))     # j == k - 0: duplicate stamp; otherwise an older stamp
        t.insert(k + 1, t[j]), r.insert(k + 1, 99.0), u.insert(k + 1, -99.0), y.insert(k + 1, 1e6)
    t, r, u, y = (np.array(v) for v in (t, r, u, y))
    pipe = MonitorPipeline(_config())
    reps = []
    for a in range(0, t.size, 37):
        reps += pipe.push(t[a:a + 37], r[a:a + 37], u[a:a + 37], y[a:a + 37])
    assert [x.time_s for x in reps] == [x.time_s for x in rep_ref]
    assert np.array_equal(pipe.est.get_state()["theta"], ref.est.get_state()["theta"])
    assert pipe.counters.duplicates + pipe.counters.out_of_order == 40
    assert pipe.counters.samples_dropped == 40
    # reported (a short hold: dropped stamps do not move the estimate, so the issue lapses after the hold-off)
    assert any({"out_of_order", "duplicate_stamps"} & set(x.health["issues"]) for x in reps)


def test_sensor_problems_are_health_not_structural(healthy_sim):
    sim = healthy_sim
    n = int(450.0 * 20)
    t, r, u, y = sim.t[:n].copy(), sim.r[:n].copy(), sim.u[:n].copy(), sim.y[:n].copy()
    y[int(300 * 20):int(300 * 20) + 30] = np.nan                     # NaN burst (1.5 s)
    y[int(330 * 20):int(340 * 20)] = y[int(330 * 20)]                 # stuck for 10 s
    keep = np.ones(n, dtype=bool)
    keep[int(360 * 20):int(362 * 20)] = False                          # 2 s data gap
    t, r, u, y = t[keep], r[keep], u[keep], y[keep]
    pipe = MonitorPipeline(_config())
    reps = pipe.push(t, r, u, y)
    assert [e for x in reps for e in x.events_opened] == []
    by_t = {x.time_s: x for x in reps}
    # (after the gap the estimator re-primes its filters: the tests stay held, the reason says why)
    for t_check, issue in ((301.0, "nonfinite"), (335.0, "stuck_sensor"), (362.0, "data_gap"), (363.0, "repriming")):
        h = by_t[t_check].health
        assert h["hold"] and issue in h["issues"] and h["level"] >= 1
    c = pipe.counters
    assert c.nonfinite == 30 and c.gaps == 1 and c.stuck_episodes == 1
    assert pipe.est.health.reprimes >= 2                              # after the stuck episode and the gap
    assert np.all(np.isfinite(reps[-1].modal))
    # the estimate after recovery is still the healthy plant's (closed-loop bias within 5 %, NOTES)
    assert reps[-1].modal[1, 0] == pytest.approx(PAPER_MODES[1].natural_frequency_hz, rel=0.05)


def test_state_roundtrip_continues_identically():
    sim = _simulate(400.0)
    ref = MonitorPipeline(_config())
    rep_ref = ref.push(sim.t, sim.r, sim.u, sim.y)
    half = int(310.0 * 20)
    a = MonitorPipeline(_config())
    a.push(sim.t[:half], sim.r[:half], sim.u[:half], sim.y[:half])
    assert a.phase in ("learning", "monitoring")
    state = json.loads(json.dumps(a.get_state()))
    b = MonitorPipeline(_config(), state=state)
    rep_b = b.push(sim.t[half:], sim.r[half:], sim.u[half:], sim.y[half:])
    tail = [x for x in rep_ref if x.time_s >= rep_b[0].time_s]
    assert [x.time_s for x in rep_b] == [x.time_s for x in tail]
    assert all(np.array_equal(x.modal, y.modal, equal_nan=True) for x, y in zip(rep_b, tail, strict=True))
    assert np.array_equal(b.faults.baseline_arrays()[0], ref.faults.baseline_arrays()[0], equal_nan=True)
    with pytest.raises(PipelineError, match="K=3"):
        MonitorPipeline(MonitorConfig.from_params({**_config().params, "modes.natural_frequency_hz": [0.3, 0.8],
                                                   "modes.damping_ratio": [0.2, 0.02], "modes.gain": [3.0, 0.5],
                                                   "modes.memory_s": [20.0, 20.0], "modes.integrators": [0, 0]}),
                        state=state)


def test_runtime_parameters_and_input_errors():
    pipe = MonitorPipeline(_config())
    pipe.update_params({"modes.memory_s": [30.0, 30.0, 10.0], "faults.min_change.gain": 0.3,
                        "publish_rate_hz": 5.0})
    assert np.allclose(pipe.est.forgetting, 1.0 - 1.0 / (np.array([30.0, 30.0, 10.0]) * 20.0))
    assert pipe.faults.settings.min_change[2] == 0.3 and pipe.faults.memory_s.tolist() == [30.0, 30.0, 10.0]
    with pytest.raises(PipelineError, match="memory_s"):
        pipe.update_params({"modes.memory_s": [30.0, 30.0]})      # K = 3 (one value would mean all modes)
    with pytest.raises(PipelineError, match="min_change"):
        pipe.update_params({"faults.min_change.gain": -1.0})
    with pytest.raises(PipelineError, match="equal length"):
        pipe.push(np.arange(3) / 20.0, np.zeros(3), np.zeros(2), np.zeros(3))
    assert pipe.push(np.array([]), None, np.array([]), np.array([])) == []
