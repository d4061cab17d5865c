"""Simulator (core/simulate.py) against independent discretizations (scipy), causality, faults, generators."""
import math

import numpy as np
import pytest
from scipy import signal
from scipy.linalg import expm

from additive_rsrivc_ros.core.controller import DiscreteController
from additive_rsrivc_ros.core.model import SubmodelStructure
from additive_rsrivc_ros.core.plant import closed_loop_poles
from additive_rsrivc_ros.sim.plants import PAPER_MODES, PAPER_PID
from additive_rsrivc_ros.sim.simulate import (
    ModalChange,
    PlantMode,
    SensorFault,
    arma_noise,
    modal_trajectories,
    multisine,
    prbs,
    simulate,
    simulate_modes,
    square_wave,
    sum_of_sines,
    thetas_from_modal,
    time_vector,
    white_noise,
)

PID = PAPER_PID  # 001 §5.2 / NOTES erratum 1
PAPER = list(PAPER_MODES)  # 000 §5: a2 = [0.25, 0.04, 0.0025]
BEAM = [PlantMode(3.25, 0.235, 11.81), PlantMode(33.0, 0.0171, 0.159), PlantMode(171.7, 0.0056, 3.19e-4),
        PlantMode(183.2, 0.002, 1.27e-4)]
MIXED = [PlantMode(0.0, 0.0, 2.0, integrators=2), PlantMode(5.0, 0.05, 0.3),
         PlantMode(2.0, 0.3, 0.5, integrators=1)]


def _tf(m: PlantMode) -> tuple[np.ndarray, np.ndarray]:
    """Continuous transfer function of one mode, descending powers of s (for scipy)."""
    if m.rigid:
        return np.array([m.gain]), np.r_[1.0, np.zeros(m.integrators)]
    w = 2 * np.pi * m.natural_frequency_hz
    return np.array([m.gain]), np.r_[1 / w**2, 2 * m.damping_ratio / w, 1.0, np.zeros(m.integrators)]


def _scipy_open_loop(modes, u, rate, delay):
    """Independent reference: cont2discrete(zoh) of each mode's transfer function, lfilter, delay, sum."""
    ud = np.r_[np.zeros(delay), u[: u.size - delay]]
    out = np.zeros_like(u)
    for m in modes:
        num, den = _tf(m)
        numd, dend, _ = signal.cont2discrete((num, den), 1 / rate, method="zoh")
        out += signal.lfilter(np.ravel(numd), dend, ud)
    return out


@pytest.mark.parametrize("modes,rate,delay", [(PAPER, 20.0, 0), (BEAM, 4096.0, 4), (MIXED, 200.0, 2)])
def test_constant_parameters_match_scipy_zoh(modes, rate, delay):
    n = 4000
    rng = np.random.default_rng(1)
    u = white_noise(n, 1.0, rng)
    if any(m.integrators for m in modes):
        u -= u.mean()  # keep the integrator chains bounded so the comparison is relative to O(1) values
    res = simulate_modes(modes, rate, u=u, input_delay=delay)
    ref = _scipy_open_loop(modes, u, rate, delay)
    # both are exact ZOH; differences are rounding, amplified at most by the filter's condition (<< 1e-10 rel.)
    np.testing.assert_allclose(res.x, ref, rtol=0, atol=1e-10 * np.abs(ref).max())
    np.testing.assert_array_equal(res.y, res.x)  # no noise given
    assert res.r is None


def _expm_reference(modes, modal, u, rate, delay):
    """Per-sample exact ZOH with scipy.linalg.expm in output coordinates [x, x', ...] (state carried)."""
    h = 1.0 / rate
    ud = np.r_[np.zeros(delay), u[: u.size - delay]]
    n = u.size
    out = np.zeros(n)
    for i, m in enumerate(modes):
        ns = m.integrators + (0 if m.rigid else 2)
        z = np.zeros(ns)
        for k in range(n):
            out[k] += z[0]
            f, zeta, g = modal[i, k]
            a = np.zeros((ns, ns))
            a[:-1, 1:] = np.eye(ns - 1)
            b = np.zeros(ns)
            if m.rigid:
                b[-1] = g
            else:
                w = 2 * np.pi * f
                a[-1, m.integrators] = -w**2
                a[-1, m.integrators + 1] = -2 * zeta * w
                b[-1] = g * w**2
            aug = np.zeros((ns + 1, ns + 1))
            aug[:ns, :ns], aug[:ns, ns] = a * h, b * h
            e = expm(aug)
            z = e[:ns, :ns] @ z + e[:ns, ns] * ud[k]
    return out


def test_time_varying_parameters_match_expm_with_carried_state():
    rate, n = 100.0, 1500
    t = np.arange(n) / rate
    changes = [ModalChange(1, "frequency", -0.3, 3.0), ModalChange(1, "damping", 1.5, 5.0),
               ModalChange(2, "gain", -0.4, 4.0), ModalChange(0, "gain", 0.5, 6.0, 2.0, "ramp"),
               ModalChange(2, "frequency", 0.2, 8.0, 3.0, "bump")]
    u = square_wave(t, 0.7) + 0.3 * white_noise(n, 1.0, np.random.default_rng(3))
    u -= u.mean()
    res = simulate_modes(MIXED, rate, u=u, changes=changes, input_delay=1)
    ref = _expm_reference(MIXED, res.modal, u, rate, 1)
    np.testing.assert_allclose(res.x, ref, rtol=0, atol=1e-10 * np.abs(ref).max())
    # the parameters really changed (a test that cannot fail otherwise)
    assert res.modal[1, -1, 0] == pytest.approx(0.7 * 5.0) and res.modal[2, -1, 2] == pytest.approx(0.6 * 0.5)
    assert res.modal[2, int(9.5 * rate), 0] == pytest.approx(2.0 * 1.2)  # bump at its top at the middle


def test_modal_truth_and_thetas():
    t = np.arange(0, 10, 0.01)
    modal = modal_trajectories(PAPER, t, [ModalChange(0, "frequency", -0.2, 2.0, 4.0, "raised_cosine")])
    th = thetas_from_modal(modal, PAPER)
    assert modal.shape == (3, t.size, 3)
    np.testing.assert_allclose(th[1][0], [0.01, 0.04, 0.5], rtol=1e-12)  # 000 §5 theta_2
    np.testing.assert_allclose(modal[0, t >= 6.0, 0], 0.8 / (2 * np.pi * 0.5), rtol=1e-12)
    assert np.all(np.diff(modal[0, :, 0]) <= 0)  # monotone ramp
    with pytest.raises(ValueError, match="rigid"):
        modal_trajectories(MIXED, t, [ModalChange(0, "frequency", -0.1, 1.0)])


def test_closed_loop_is_the_causal_sampled_loop():
    rate = 20.0
    t = time_vector(rate, 200.0)
    r = sum_of_sines(t, [3, 1, 1, 1], [0.005, 2, 5, 17.5])
    v = white_noise(t.size, 0.1, np.random.default_rng(0))
    changes = [ModalChange(0, "frequency", -0.2, 50.0, 100.0, "raised_cosine")]
    res = simulate_modes(PAPER, rate, r=r, controller=PID, noise=v, input_delay=1, changes=changes)
    np.testing.assert_array_equal(res.y, res.x + v)
    # u(t_k) = C_d(q)(r - y)(t_k)  (000 eq. 10) from rest
    np.testing.assert_allclose(res.u, PID.apply(r - res.y), rtol=0, atol=1e-12 * np.abs(res.u).max())
    # the plant output is the open-loop response to the recorded u (time-varying reference with expm)
    ref = _expm_reference(PAPER, res.modal, res.u, rate, 1)
    np.testing.assert_allclose(res.x, ref, rtol=0, atol=1e-10 * np.abs(ref).max())
    # causality: a change of r at sample k changes u from k on and x only from k + 1 + delay on
    k, d = 1000, 1
    r2 = r.copy()
    r2[k] += 1.0
    res2 = simulate_modes(PAPER, rate, r=r2, controller=PID, noise=v, input_delay=d, changes=changes)
    np.testing.assert_array_equal(res2.u[:k], res.u[:k])
    assert res2.u[k] != res.u[k]
    np.testing.assert_array_equal(res2.x[: k + 1 + d], res.x[: k + 1 + d])
    assert res2.x[k + 1 + d] != res.x[k + 1 + d]


def test_closed_loop_poles_predict_growth():
    """NOTES erratum 1: the printed -0.2058 is unstable (max |pole| ~ 1.24); the corrected PID is stable."""
    th0 = [thetas_from_modal(modal_trajectories(PAPER, np.zeros(1)), PAPER)[i][0] for i in range(3)]
    st = [m.structure for m in PAPER]
    good = np.abs(closed_loop_poles(th0, st, PID, 20.0)).max()
    bad_c = DiscreteController((0.02329, -0.2058, 0.00454), (1.0, -1.0, 0.0))
    bad = np.abs(closed_loop_poles(th0, st, bad_c, 20.0)).max()
    assert good < 1.0 < bad
    # the simulated loop grows at the rate of the dominant pole: |y| ~ bad^k (log slope within 2 %)
    t = time_vector(20.0, 30.0)
    res = simulate_modes(PAPER, 20.0, r=np.r_[1.0, np.zeros(t.size - 1)], controller=bad_c)
    env = np.log(np.maximum.accumulate(np.abs(res.x[1:])))
    slope = (env[-1] - env[300]) / (env.size - 1 - 300)
    assert slope == pytest.approx(math.log(bad), rel=0.02)


def test_sensor_faults_on_measurement():
    rate = 20.0
    t = time_vector(rate, 100.0)
    r = sum_of_sines(t, [1, 1], [0.5, 2.0])
    faults = [SensorFault("bias", 10.0, 10.0, 0.5), SensorFault("drift", 30.0, 10.0, 0.1),
              SensorFault("stuck", 50.0, 5.0, None), SensorFault("nan", 60.0, 20.0, fraction=0.1),
              SensorFault("drop", 85.0, 10.0, fraction=0.2)]
    v = white_noise(t.size, 0.01, np.random.default_rng(5))
    res = simulate_modes(PAPER, rate, r=r, controller=PID, noise=v, sensor_faults=faults,
                         rng=np.random.default_rng(7))
    clean = res.x + v
    win = lambda a, b: (t >= a) & (t < b)  # noqa: E731
    np.testing.assert_allclose(res.y[win(10, 20)], clean[win(10, 20)] + 0.5, atol=1e-12)
    np.testing.assert_allclose(res.y[win(30, 40)], clean[win(30, 40)] + 0.1 * (t[win(30, 40)] - 30), atol=1e-12)
    stuck = res.y[win(50, 55)]
    assert np.all(stuck == stuck[0]) and stuck[0] == pytest.approx(clean[1000], abs=1e-12)
    nan = np.isnan(res.y)
    assert nan.sum() == res.nan_mask.sum() and np.all(win(60, 80)[nan])
    assert 0.1 * 400 - 4 * math.sqrt(400 * 0.09) < nan.sum() < 0.1 * 400 + 4 * math.sqrt(400 * 0.09)
    dropped = np.flatnonzero(res.drop_mask)
    assert dropped.size > 0 and np.all(win(85, 95)[dropped])
    for k in dropped:
        assert res.y[k] == res.y[k - 1]
    ok = ~res.drop_mask & ~nan & win(0, 10) | win(20, 30) | win(41, 50) | win(55, 60)
    np.testing.assert_array_equal(res.y[ok], clean[ok])
    # the controller saw the faulty sensor and held its last finite value on NaN samples
    y_ctrl = res.y.copy()
    for k in np.flatnonzero(nan):
        y_ctrl[k] = y_ctrl[k - 1]
    np.testing.assert_allclose(res.u, PID.apply(r - y_ctrl), atol=1e-12 * np.abs(res.u).max())


def test_generators():
    rng = np.random.default_rng(11)
    t = time_vector(1000.0, 20.0)
    assert t.size == 20000 and t[1] == 1e-3
    ms = multisine(t, [1.0, 2.0, 5.0, 13.0], rms=2.0, rng=rng)  # integer periods in 20 s: exact RMS
    assert np.sqrt(np.mean(ms**2)) == pytest.approx(2.0, rel=1e-6)
    sq = square_wave(t, 2.0, amplitude=0.5, offset=1.0)
    assert set(np.unique(sq)) == {0.5, 1.5} and np.mean(sq) == pytest.approx(1.0, abs=1e-9)
    assert np.count_nonzero(np.diff(sq)) == 2 * 2 * 20 - 1  # two switches per period
    p = prbs(5000, 0.3, rng, nbits=9, hold=3)
    assert set(np.unique(p)) == {-0.3, 0.3} and np.all(p[0:3] == p[0])
    # a maximum-length sequence of period 511 has exactly one more +1 than -1 per period
    assert abs(prbs(511, 1.0, rng, nbits=9).sum()) == 1.0
    n = 200000
    v = arma_noise(n, 0.2, rng, c=[1.0, 0.5], d=[1.0, -0.9])
    # std of a sample std of a correlated series: generous 5 % (effective samples ~ n (1-0.9)/(1+0.9))
    assert np.std(v) == pytest.approx(0.2, rel=0.05)
    rho1 = np.corrcoef(v[:-1], v[1:])[0, 1]
    assert rho1 > 0.8  # coloured, not white
    w = white_noise(n, 0.2, rng)
    assert np.std(w) == pytest.approx(0.2, rel=5 / math.sqrt(2 * n))


def test_bad_input():
    with pytest.raises(ValueError):
        PlantMode(0.0, 0.0, 1.0)  # rigid body without integrators
    with pytest.raises(ValueError):
        ModalChange(0, "stiffness", -0.1, 1.0)
    with pytest.raises(ValueError):
        simulate([np.array([0.1, 0.01, 1.0])], [SubmodelStructure()], 20.0, u=np.r_[1.0, np.nan])
    with pytest.raises(ValueError, match="closed loop"):
        simulate([np.array([0.1, 0.01, 1.0])], [SubmodelStructure()], 20.0, u=np.ones(3), controller=PID)
    with pytest.raises(ValueError, match="shape"):
        simulate([np.ones((4, 3))], [SubmodelStructure()], 20.0, u=np.ones(3))
    with pytest.raises(ValueError):
        time_vector(20.0, -1.0)
