"""Named scenarios (core/scenarios.py): truth, determinism, closed-loop stability, configs, fault schedules."""
import math

import numpy as np
import pytest

from additive_rsrivc_ros.core.plant import closed_loop_poles, loop_margins
from additive_rsrivc_ros.sim.plants import BEAM_MODES
from additive_rsrivc_ros.sim.scenarios import SCENARIOS, build, list_scenarios
from additive_rsrivc_ros.sim.simulate import (
    PlantMode,
    simulate_modes,
    thetas_from_modal,
)

SHORT = {"paper_example": 200.0, "beam": 6.0, "beam_fault": 6.0, "beam_healthy": 4.0, "open_loop_multisine": 20.0,
         "rigid_body": 20.0, "sensor_fault": 600.0}


def _frozen(data, k: int) -> list[np.ndarray]:
    """Plant thetas (every plant mode, estimated or not) at sample k."""
    return [th[k] for th in data.sim.theta]


def test_every_scenario_is_listed_with_a_config():
    assert set(list_scenarios()) == {"paper_example", "beam", "beam_fault", "beam_healthy", "open_loop_multisine",
                                     "rigid_body", "sensor_fault"}
    assert set(SHORT) == set(SCENARIOS)


@pytest.mark.parametrize("name", sorted(SHORT))
def test_scenario_is_deterministic_stable_and_consistent(name):
    data = build(name, duration_s=SHORT[name], seed=3)
    cfg = data.config
    assert data.config_path.name == f"{name}.yaml" and data.config_path.exists()
    n = int(round(SHORT[name] * cfg.loop_rate_hz))
    assert data.t.size == data.u.size == data.y.size == n
    assert data.truth.shape == (cfg.K, n, 3) and data.truth_all.shape[0] >= cfg.K
    np.testing.assert_array_equal(data.truth, data.truth_all[: cfg.K])
    # the configured initial guesses are the truth at t = 0 (to the 4-5 digits written in the YAML)
    guess = np.array([[m.natural_frequency_hz, m.damping_ratio, m.gain] for m in cfg.modes])
    np.testing.assert_allclose(data.truth[:, 0, :], guess, rtol=2e-3, atol=1e-12)
    for i, m in enumerate(cfg.modes):
        assert data.sim.structures[i].integrators == m.integrators
    # deterministic for a seed, different for another seed
    again = build(name, duration_s=SHORT[name], seed=3)
    np.testing.assert_array_equal(again.y, data.y)
    np.testing.assert_array_equal(again.u, data.u)
    assert again.fault_events == data.fault_events
    other = build(name, duration_s=SHORT[name], seed=4)
    assert not np.array_equal(np.nan_to_num(other.y), np.nan_to_num(data.y))
    if cfg.closed_loop:
        assert data.r is not None
        u_ref = cfg.controller.apply(data.r - np.nan_to_num(data.y))[:100]
        np.testing.assert_allclose(data.u[:100], u_ref, rtol=0, atol=1e-12 * np.abs(u_ref).max())
        # frozen closed loop is stable at every 1/20 of the run (covers the ramps' extremes to 5 %)
        for k in np.linspace(0, n - 1, 21).astype(int):
            poles = closed_loop_poles(_frozen(data, k), data.sim.structures, cfg.controller, cfg.loop_rate_hz,
                                      cfg.input_delay_samples)
            assert np.abs(poles).max() < 1.0, (name, k)
    else:
        assert data.r is None
    # bounded response: |x| stays within a few times the excitation's steady level (no growth at the end)
    x = data.x
    first, last = np.abs(x[: n // 2]).max(), np.abs(x[n // 2:]).max()
    assert np.isfinite(x).all() and last < 3.0 * first + 1e-12


def test_paper_example_truth_follows_000_s5():
    data = build("paper_example", seed=0)  # full 1000 s at 20 Hz
    t, tr = data.t, data.truth
    f0 = np.array([1 / (2 * math.pi * math.sqrt(a2)) for a2 in (0.25, 0.04, 0.0025)])
    z0 = np.array([0.25 / (2 * 0.5), 0.01 / (2 * 0.2), 0.01 / (2 * 0.05)])
    np.testing.assert_allclose(tr[:, 0, 0], f0, rtol=1e-12)
    np.testing.assert_allclose(tr[:, 0, 1], z0, rtol=1e-12)
    end = t >= 800.0
    np.testing.assert_allclose(tr[0, end, 0], 0.8 * f0[0], rtol=1e-12)
    np.testing.assert_allclose(tr[1, end, 1], 0.5 * z0[1], rtol=1e-12)
    np.testing.assert_allclose(tr[2, end, 0], 0.85 * f0[2], rtol=1e-12)
    np.testing.assert_allclose(tr[2, end, 1], 0.7 * z0[2], rtol=1e-12)
    np.testing.assert_array_equal(tr[:, :, 2], np.array([3.0, 0.5, 1.0])[:, None] * np.ones(t.size))
    assert np.all(tr[0, t <= 100.0, 0] == f0[0]) and np.all(tr[2, t <= 500.0, 0] == f0[2])
    # NOTES erratum 1: the corrected PID keeps max |pole| <= 0.9987 along the whole trajectory
    worst = max(np.abs(closed_loop_poles(_frozen(data, k), data.sim.structures, data.config.controller, 20.0))
                .max() for k in range(0, t.size, 200))
    assert worst <= 0.9990
    # white noise of variance 0.01 (000 §5): sample variance within 4 sigma of 0.01
    v = data.sim.v
    assert abs(v.var() - 0.01) < 4 * 0.01 * math.sqrt(2 / v.size)
    assert [e["event"] for e in data.fault_events] == ["start", "onset", "onset", "complete", "complete", "onset",
                                                       "onset", "complete", "complete"]


def test_beam_truth_noise_and_controller_margins():
    data = build("beam", seed=0)  # 120 s at 4096 Hz
    f2 = data.truth[1, :, 0]
    f2_0 = BEAM_MODES[1].natural_frequency_hz
    assert 32.9 < f2_0 < 33.1 and data.truth_all.shape[0] == 4 and data.config.K == 2
    assert np.all(f2[data.t <= 40.0] == f2_0) and np.all(f2[data.t >= 100.0] == pytest.approx(f2_0, rel=1e-12))
    assert f2.min() == pytest.approx(0.9 * f2_0, rel=1e-6) and data.t[np.argmin(f2)] == pytest.approx(70.0, abs=1e-3)
    np.testing.assert_array_equal(data.truth[1, :, 1:], data.truth[1, :1, 1:] * np.ones((data.t.size, 1)))
    # output noise: a few % of the std of mode 2's contribution (computed exactly from the recorded input)
    m2 = simulate_modes([BEAM_MODES[1]], 4096.0, u=data.u[:4096 * 20], input_delay=4)
    ratio = data.sim.v.std() / m2.x[4096:].std()
    assert 0.01 < ratio < 0.10
    # the designed controller stabilizes the loop with margin over mode-2 frequencies 0.8..1.1 x nominal
    cfg = data.config
    for fac in (0.8, 0.9, 0.95, 1.0, 1.1):
        modes = list(BEAM_MODES)
        modes[1] = PlantMode(f2_0 * fac, BEAM_MODES[1].damping_ratio, BEAM_MODES[1].gain)
        th = [a[0] for a in thetas_from_modal(np.array([[m.modal] for m in modes]), modes)]
        m = loop_margins(th, [mm.structure for mm in modes], cfg.controller, 4096.0, 4, n_freq=3000)
        assert m["max_pole"] < 0.9999 and m["modulus_margin"] > 0.5, (fac, m)
    # it also tracks the 2 Hz square wave: error settles within each 0.25 s half period
    half = 512
    err = (data.r - data.x)[4096:4096 * 10].reshape(-1, half)
    assert np.abs(err[:, -50:]).max() < 0.2 * 0.1


def test_beam_fault_schedule():
    data = build("beam_fault", duration_s=10.0, seed=1, fault_time_s=6.0)
    f2 = data.truth[1, :, 0]
    f2_0 = BEAM_MODES[1].natural_frequency_hz
    assert np.all(f2[data.t < 6.0] == f2_0)
    np.testing.assert_allclose(f2[data.t >= 6.0], 0.95 * f2_0, rtol=1e-12)
    onset = [e for e in data.fault_events if e["event"] == "onset"]
    assert len(onset) == 1 and onset[0]["time_s"] == 6.0
    assert onset[0]["fault"] | {} == {"kind": "structural", "mode": 2, "quantity": "natural_frequency",
                                      "direction": "down", "relative_change": -0.05, "shape": "step",
                                      "start_s": 6.0, "end_s": 6.0}
    mid = build("beam_fault", duration_s=8.0, seed=1)  # default fault time: the middle
    assert [e["time_s"] for e in mid.fault_events] == [0.0, 4.0]
    ramp = build("beam_fault", duration_s=8.0, seed=1, fault_ramp_s=1.0)
    assert [e["event"] for e in ramp.fault_events] == ["start", "onset", "complete"]


def test_sensor_fault_scenario():
    data = build("sensor_fault", seed=0)
    t, y, clean = data.t, data.y, data.x + data.sim.v
    nan = np.isnan(y)
    assert nan.sum() > 0 and np.all((t[nan] >= 350.0) & (t[nan] < 400.0))
    ok = (t >= 150.0) & ~nan & ~data.sim.drop_mask & ~((t >= 250.0) & (t < 255.0))
    np.testing.assert_allclose(y[ok] - clean[ok], 0.5, atol=1e-12)  # bias step from 150 s
    np.testing.assert_array_equal(y[t < 150.0], clean[t < 150.0])
    stuck = y[(t >= 250.0) & (t < 255.0)]
    assert np.all(stuck == stuck[0])
    assert data.sim.drop_mask.sum() > 0
    kinds = {e["fault"]["type"] for e in data.fault_events if e["event"] == "onset"}
    assert kinds == {"bias", "stuck", "nan", "drop"}
    assert np.all(data.truth[:, :, 0] == data.truth[:, :1, 0])  # healthy plant


def test_rigid_body_and_open_loop_configs():
    rb = build("rigid_body", duration_s=5.0)
    assert rb.config.modes[0].natural_frequency_hz == 0.0 and rb.config.modes[0].integrators == 2
    assert np.all(rb.truth[0, :, :2] == 0.0) and np.all(rb.truth[0, :, 2] == 1.0)
    ol = build("open_loop_multisine", duration_s=20.0)
    assert not ol.config.closed_loop and ol.r is None
    # 20 s is one multisine period: the input's RMS is the configured 1.0 exactly
    assert np.sqrt(np.mean(ol.u**2)) == pytest.approx(1.0, rel=1e-6)


def test_bad_requests():
    with pytest.raises(ValueError, match="unknown scenario"):
        build("nope")
    with pytest.raises(ValueError, match="no parameter"):
        build("beam", duration_s=1.0, fault_time_s=3.0)
    with pytest.raises(ValueError, match="duration"):
        build("beam", duration_s=-1.0)
    with pytest.raises(ValueError, match="seed"):
        build("beam", duration_s=1.0, seed=-2)
