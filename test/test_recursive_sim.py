"""Checks of the independent reference generator ``sim.independent.simulate_modal`` (ZOH-exact modes, input held
between samples, optional input delay and closed loop, 000 Assumption 5) against scipy and the loop equation."""

from __future__ import annotations

import numpy as np
from scipy import signal

from additive_rsrivc_ros.core.model import theta_from_modal
from additive_rsrivc_ros.sim.independent import PAPER_THETA, PID, paper_reference, simulate_modal


def test_generator_matches_scipy_zoh_open_loop():
    """Open loop, delay 2: equals scipy's ZOH discretization of sum b0/A run by lsim (dlsim)."""
    rate, n = 20.0, 400
    rng = np.random.default_rng(1)
    u = rng.standard_normal(n)
    _, y = simulate_modal(PAPER_THETA, rate, n, u=u, delay=2)
    yr = np.zeros(n)
    for th in PAPER_THETA:
        sysd = signal.cont2discrete(([th[2]], [th[1], th[0], 1.0]), 1 / rate, method="zoh")
        _, yo = signal.dlsim((sysd[0].ravel(), sysd[1], sysd[2]), np.concatenate((np.zeros(2), u[:-2])))
        yr += yo.ravel()
    np.testing.assert_allclose(y, yr, atol=1e-10 * np.abs(yr).max())


def test_generator_closed_loop_equation():
    """Closed loop: the generated u satisfies the controller's difference equation on r - y exactly."""
    rate, n = 20.0, 600
    t = np.arange(n) / rate
    r = paper_reference(t)
    u, y = simulate_modal(PAPER_THETA, rate, n, r=r, controller=PID)
    np.testing.assert_allclose(u, PID.apply(r - y), atol=1e-12 * np.abs(u).max())
    assert np.all(np.isfinite(y)) and np.abs(y).max() < 50.0


def test_generator_dc_gain():
    """A unit step settles at the DC gain sum b0 (A(0) = 1)."""
    w = 2 * np.pi * 5.0
    th = [theta_from_modal(5.0, 0.3, 2.0)]
    _, y = simulate_modal(th, 1000.0, 4000, u=np.ones(4000))
    assert abs(y[-1] - 2.0) < 1e-6 and w > 0
