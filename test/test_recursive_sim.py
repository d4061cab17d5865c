"""Test-local ZOH-exact data for the recursive engine, and checks of that generator itself.

``simulate_modal`` is a plain reference plant (the package simulator lives in core/simulate.py): modes
``b0/(a2 p^2 + a1 p + 1)`` (or a rigid body ``b0/p^l``) in physical coordinates, input held between
samples (ZOH), optional input delay, optional closed loop ``u_k = C_d(q)(r_k - y_k)`` with the
controller's difference equation, optional white output noise, parameters piecewise constant between
samples (000 Assumption 5).
"""
import numpy as np
from numba import njit
from scipy import signal

from additive_rsrivc_ros.core.model import theta_from_modal
from additive_rsrivc_ros.core.zoh import integrator_chain_zoh, second_order_zoh
from additive_rsrivc_ros.sim.plants import PAPER_PID, PAPER_THETAS

PID = PAPER_PID  # NOTES erratum 1
PAPER_THETA = PAPER_THETAS


@njit(cache=False)
def _sim(theta_traj, kinds, h, delay, closed, cnum, cden, r, u_ext, noise):  # pragma: no cover - compiled
    n, K = theta_traj.shape[0], theta_traj.shape[1]
    x = np.zeros((K, 2))
    phi = np.zeros((2, 2))
    gam = np.zeros(2)
    ubuf = np.zeros(delay + 1)
    ce = np.zeros(cnum.size)
    cz = np.zeros(cden.size)
    u = np.zeros(n)
    y = np.zeros(n)
    pos = 0
    for k in range(n):
        yk = 0.0
        for i in range(K):
            ib = 2 if kinds[i] == 0 else 0
            yk += theta_traj[k, i, ib] * x[i, 0]
        y[k] = yk + noise[k]
        if closed:
            e = r[k] - y[k]
            for j in range(ce.size - 1, 0, -1):
                ce[j] = ce[j - 1]
            ce[0] = e
            uk = 0.0
            for j in range(cnum.size):
                uk += cnum[j] * ce[j]
            for j in range(1, cden.size):
                uk -= cden[j] * cz[j - 1]
            for j in range(cz.size - 1, 0, -1):
                cz[j] = cz[j - 1]
            cz[0] = uk
        else:
            uk = u_ext[k]
        u[k] = uk
        ubuf[pos] = uk
        pos = (pos + 1) % (delay + 1)
        ud = ubuf[pos]  # u_{k-d}
        for i in range(K):
            phi[:, :] = 0.0
            gam[:] = 0.0
            if kinds[i] == 0:
                second_order_zoh(theta_traj[k, i, 0], theta_traj[k, i, 1], h, phi, gam)
            else:
                integrator_chain_zoh(kinds[i], h, phi[:kinds[i], :kinds[i]], gam[:kinds[i]])
            x0 = phi[0, 0] * x[i, 0] + phi[0, 1] * x[i, 1] + gam[0] * ud
            x1 = phi[1, 0] * x[i, 0] + phi[1, 1] * x[i, 1] + gam[1] * ud
            x[i, 0] = x0
            x[i, 1] = x1
    return u, y


def simulate_modal(theta, rate_hz, n, *, r=None, u=None, controller=None, delay=0, noise_std=0.0, seed=0,
                   kinds=None):
    """Return ``(u, y)``: theta is a list of K vectors (constant) or an array (n, K, 3) (time-varying)."""
    if isinstance(theta, list):
        traj = np.zeros((n, len(theta), 3))
        for i, t in enumerate(theta):
            traj[:, i, :len(t)] = t
    else:
        traj = np.ascontiguousarray(theta, dtype=float)
    K = traj.shape[1]
    kinds = np.zeros(K, dtype=np.int64) if kinds is None else np.asarray(kinds, dtype=np.int64)
    closed = controller is not None
    cnum = controller.num if closed else np.zeros(1)
    cden = controller.den if closed else np.ones(1)
    rng = np.random.default_rng(seed)
    noise = noise_std * rng.standard_normal(n)
    r = np.zeros(n) if r is None else np.asarray(r, dtype=float)
    u_ext = np.zeros(n) if u is None else np.asarray(u, dtype=float)
    return _sim(traj, kinds, 1.0 / rate_hz, int(delay), closed, np.asarray(cnum, float), np.asarray(cden, float),
                r, u_ext, noise)


def paper_reference(t):
    """000 §5 setpoint ``3 sin(0.005 t) + sin 2t + sin 5t + sin 17.5t``."""
    return 3 * np.sin(0.005 * t) + np.sin(2 * t) + np.sin(5 * t) + np.sin(17.5 * t)


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
