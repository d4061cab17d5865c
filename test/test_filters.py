"""ZOH-exact filter bank (core/estimation/filters.py) against independent references with known truth."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from additive_rsrivc_ros.core.controller import DiscreteController
from additive_rsrivc_ros.core.estimation import filters as F
from additive_rsrivc_ros.core.model import SubmodelStructure, theta_from_modal
from additive_rsrivc_ros.sim.independent import MODE, PAPER_THETAS, PID_DEN, PID_NUM, simulate
from additive_rsrivc_ros.sim.plants import PAPER_PID
from additive_rsrivc_ros.sim.plants import PAPER_THETAS as PAPER5_THETAS

EPS = np.finfo(float).eps


def _scipy_zoh(num_asc, den_asc, h, v):
    numd, dend, _ = signal.cont2discrete((np.asarray(num_asc)[::-1], np.asarray(den_asc)[::-1]), h, method="zoh")
    return signal.lfilter(numd.ravel(), dend, v)


def test_svf_matches_scipy_zoh_at_moderate_rate():
    """p^j/A v for j = 0..n equals scipy's ZOH equivalent (well conditioned case, h = 0.05)."""
    rng = np.random.default_rng(0)
    v = rng.standard_normal(3000)
    a = np.array([1.0, 0.25, 0.25])
    bank = F.svf(a, v, 0.05)
    for j in range(3):
        ref = _scipy_zoh(np.eye(3)[j], a, 0.05, v)
        # scipy goes through polynomials: its own rounding is ~1e-13 relative here
        assert np.max(np.abs(bank[:, j] - ref)) <= 1e-10 * np.max(np.abs(ref))


def test_instrument_is_one_zoh_filter_of_the_held_input():
    """p^j B/A^2 v (001 eq. 10) equals the ZOH equivalent of the product transfer function."""
    rng = np.random.default_rng(1)
    v = rng.standard_normal(3000)
    th = np.array([0.25, 0.25, 3.0])
    ins = F.instrument_filter(th, MODE, v, 0.05)
    a = np.array([1.0, 0.25, 0.25])
    a2 = np.polynomial.polynomial.polymul(a, a)
    for j in range(3):
        ref = _scipy_zoh(3.0 * np.eye(5)[j], a2, 0.05, v)
        assert np.max(np.abs(ins[:, j] - ref)) <= 1e-8 * np.max(np.abs(ref))


@pytest.mark.parametrize("f_hz,zeta", [(3.0, 0.02), (183.0, 0.002), (33.0, 0.05)])
def test_lightly_damped_modes_at_4096hz_match_the_analytic_step_response(f_hz, zeta):
    """Step through 1/A and p/A: samples of the exact continuous step/impulse response (full precision)."""
    h = 1.0 / 4096
    th = theta_from_modal(f_hz, zeta, 1.0)
    a = np.concatenate(([1.0], th[:2]))
    n = 4096 * 2
    bank = F.svf(a, np.ones(n), h)
    t = np.arange(n) * h
    w = 2 * np.pi * f_hz
    wd = w * np.sqrt(1 - zeta**2)
    env = np.exp(-zeta * w * t)
    step = 1 - env * (np.cos(wd * t) + zeta / np.sqrt(1 - zeta**2) * np.sin(wd * t))
    impulse = w**2 / wd * env * np.sin(wd * t)      # d/dt of the step response = p/A applied to a step
    # expm and the scaled realization keep ~1e3 eps relative to the signal amplitude
    assert np.max(np.abs(bank[:, 0] - step)) <= 1e4 * EPS * np.max(np.abs(step))
    assert np.max(np.abs(bank[:, 1] - impulse)) <= 1e4 * EPS * np.max(np.abs(impulse))


def test_filter_bank_reproduces_the_input_through_A_over_A():
    """sum_j a_j p^j/A v = v exactly (ZOH is linear): the identity behind the SRIVC residual (001 eq. 21)."""
    rng = np.random.default_rng(2)
    v = rng.standard_normal(20000)
    th = theta_from_modal(183.0, 0.002, 1.0)
    a = np.array([1.0, th[0], th[1]])
    bank = F.svf(a, v, 1.0 / 4096)
    rec = bank @ a
    assert np.max(np.abs(rec - v)) <= 1e-9 * np.max(np.abs(v))


def test_integrator_filters_and_submodel_output():
    """1/p^2 of a held unit step is t^2/2 at the samples; B/(p^l A) output = linear combination of the bank."""
    h = 0.01
    bank = F.svf(np.array([1.0]), np.ones(500), h, integrators=2)
    t = np.arange(500) * h
    np.testing.assert_allclose(bank[:, 0], t**2 / 2, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(bank[:, 1], t, rtol=1e-12, atol=1e-14)
    st = SubmodelStructure(n=2, m=1, integrators=1)
    th = np.array([0.1, 0.02, 2.0, 0.5])
    v = np.random.default_rng(3).standard_normal(400)
    out = F.submodel_output(th, st, v, h)
    ref = _scipy_zoh([2.0, 0.5], [0.0, 1.0, 0.1, 0.02], h, v)
    assert np.max(np.abs(out - ref)) <= 1e-9 * np.max(np.abs(ref))


@pytest.mark.parametrize("delay", [0, 3])
def test_closed_loop_response_matches_an_explicit_loop(delay):
    """z = S_uo r (001 eq. 20, NOTES erratum 3) with the input delay in G_d, vs the sample-by-sample loop."""
    h = 0.05
    r = np.random.default_rng(4).standard_normal(3000)
    u_ref, y_ref = simulate(PAPER_THETAS, [MODE, MODE], h, r=r, controller=(PID_NUM, PID_DEN), delay=delay)
    z, ycl = F.closed_loop_response(PAPER_THETAS, [MODE, MODE], h, DiscreteController(PID_NUM, PID_DEN), r, delay)
    assert np.max(np.abs(z - u_ref)) <= 1e-10 * np.max(np.abs(u_ref))
    assert np.max(np.abs(ycl - y_ref)) <= 1e-10 * np.max(np.abs(y_ref))


def test_unstable_closed_loop_is_detected():
    """The misprinted 000 §5 controller (-0.2058) does not stabilize the 000 §5 plant; the corrected one does."""
    thetas = PAPER5_THETAS
    sts = [MODE] * 3
    good = PAPER_PID
    bad = DiscreteController((0.02329, -0.2058, 0.00454), (1.0, -1.0, 0.0))
    assert F.closed_loop_radius(thetas, sts, 0.05, good) < 1.0
    rho_bad = F.closed_loop_radius(thetas, sts, 0.05, bad)
    assert rho_bad > 1.1   # NOTES erratum 1: max |pole| about 1.24
    with pytest.raises(F.ClosedLoopUnstableError, match="does not stabilize"):
        F.closed_loop_response(thetas, sts, 0.05, bad, np.ones(100))


def test_long_signal_and_large_delay_paths():
    """A 240k-sample filter run is finite and a long delay line uses the sparse eigenvalue path."""
    v = np.random.default_rng(5).standard_normal(240_000)
    th = theta_from_modal(183.0, 0.002, 1e-4)
    out = F.instrument_filter(th, MODE, v, 1.0 / 4096)
    assert out.shape == (240_000, 3) and np.all(np.isfinite(out))
    ctrl = DiscreteController(PID_NUM, PID_DEN)
    rho_dense = F.closed_loop_radius(PAPER_THETAS, [MODE, MODE], 0.05, ctrl, delay=5)
    assert rho_dense < 1.0
    rho_long = F.closed_loop_radius(PAPER_THETAS, [MODE, MODE], 0.05, ctrl, delay=600)
    assert np.isfinite(rho_long) and rho_long > 0.9


@pytest.mark.parametrize("n", [1, 2, 3, 4, 6])
def test_every_state_count_runs_the_same_recursion(n):
    """The compiled loop has register paths for 2 and 4 states and a general one: each equals the recursion
    ``x_{k+1} = phi x_k + gamma v_k``, ``Y_k = c x_k + d v_k`` written out in numpy, also into a column slice."""
    rng = np.random.default_rng(n)
    a = rng.standard_normal((n, n))
    phi = 0.9 * a / np.max(np.abs(np.linalg.eigvals(a)))
    ss = F.DiscreteSS(phi, rng.standard_normal(n), rng.standard_normal((3, n)), rng.standard_normal(3))
    v = rng.standard_normal(500)
    ref = np.empty((v.size, 3))
    x = np.zeros(n)
    for k, vk in enumerate(v):
        ref[k] = ss.c @ x + ss.d * vk
        x = ss.phi @ x + ss.gamma * vk
    scale = np.max(np.abs(ref))
    assert np.max(np.abs(ss.run(v) - ref)) <= 1e3 * EPS * scale
    wide = np.full((v.size, 5), np.nan)
    ss.run(v, rows=[2, 0], out=wide[:, 1:3], sign=-1.0)
    assert np.max(np.abs(wide[:, 1:3] + ref[:, [2, 0]])) <= 1e3 * EPS * scale
    assert np.all(np.isnan(wide[:, [0, 3, 4]]))
