"""Unstable plants and integral action (core/identification/offline/unstable.py, 003 §4-§7), CI-sized."""

from __future__ import annotations

import numpy as np
import pytest

from additive_rsrivc_ros.core.controller import DiscreteController
from additive_rsrivc_ros.core.identification.offline import identify
from additive_rsrivc_ros.core.model import SubmodelStructure
from additive_rsrivc_ros.sim.independent import MODE, simulate
from additive_rsrivc_ros.sim.plants import INT_CONTROLLER_DEN, INT_CONTROLLER_NUM

H = 0.1
ST = SubmodelStructure(n=2, m=1)
# 003 eq. 31: (-0.5 p + 1)/(p^2 + 2 xi wn p + wn^2), wn^2 = 2, xi = -0.05, anti-monic (003 Table 1 values)
TRUTH = np.array([-0.1 * np.sqrt(2) / 2, 0.5, 0.5, -0.25])
PID = ((0.0272 + 2.54e-5 + 7.29, -(0.0272 + 2 * 7.29), 7.29), (1.0, -1.0))
CTRL = DiscreteController(*PID)
TABLE1_SD = {"srivc-uns": np.array([1.49e-3, 1.00e-3, 3.82e-3, 1.17e-3]),
             "clsrivc-uns": np.array([1.53e-3, 1.12e-3, 3.96e-3, 2.10e-3])}


def _data(seed: int, noise_var: float, n: int = 15000):
    rng = np.random.default_rng(seed)
    r = rng.standard_normal(n)
    v = np.sqrt(noise_var) * rng.standard_normal(n)
    u, y = simulate([TRUTH], [ST], H, r=r, controller=PID, noise=v)
    return r, u, y


def test_noise_free_unstable_plant_recovered_from_lssvf_uns_start():
    r, u, y = _data(0, 0.0, 6000)
    start = TRUTH + np.array([0.02, -0.1, 0.0, 0.0])
    init = identify(u, y, 1 / H, [ST], [start], r=r, controller=CTRL, method="lssvf-uns")
    assert init.converged and init.extra["unstable_poles_cancelled"] == 2
    assert np.max(np.abs(init.beta - TRUTH) / np.abs(TRUTH)) < 0.3
    for method in ("srivc-uns", "clsrivc-uns"):
        res = identify(u, y, 1 / H, [ST], init.thetas, r=r, controller=CTRL, method=method, tol=1e-11)
        assert res.converged, res.message
        np.testing.assert_allclose(res.beta, TRUTH, rtol=1e-6)
        assert res.modal[0, 1] < 0    # negative damping ratio of the unstable mode is reported as such


def test_standard_srivc_cannot_return_the_unstable_model():
    """With the stability projection the ordinary estimator only delivers stable models (003 Table 1, SRIVC)."""
    r, u, y = _data(1, 0.0, 6000)
    res = identify(u, y, 1 / H, [ST], [TRUTH * 1.02], method="srivc")
    assert res.projections >= 1 and res.thetas[0][0] > 0


def test_noisy_unstable_plant_statistics():
    """003 §7.1 (CI size: 4 runs, N = 15000): means within 4 standard errors of the truth and the reported
    standard deviations within 1.5x of 003 Table 1."""
    runs = 4
    for method in ("srivc-uns", "clsrivc-uns"):
        est, pred = [], []
        for k in range(runs):
            r, u, y = _data(100 + k, 0.05)
            rng = np.random.default_rng(200 + k)
            start = TRUTH + np.array([0.02 * rng.standard_normal(), 0.1 * rng.standard_normal(), 0, 0])
            init = identify(u, y, 1 / H, [ST], [start], r=r, controller=CTRL, method="lssvf-uns")
            res = identify(u, y, 1 / H, [ST], init.thetas, r=r, controller=CTRL, method=method, tol=1e-8)
            assert res.converged, res.message
            assert res.residual_variance == pytest.approx(0.05, rel=0.1)
            est.append(res.beta)
            pred.append(np.sqrt(np.diag(res.covariance)))
        est, pred = np.array(est), np.mean(pred, axis=0)
        assert np.all(np.abs(est.mean(0) - TRUTH) <= 4 * pred / np.sqrt(runs)), method
        assert np.all(pred <= 1.5 * TABLE1_SD[method]), (method, pred / TABLE1_SD[method])


@pytest.mark.parametrize("loop", ["open", "closed"])
def test_integrator_plant_both_solutions(loop):
    """003 §7.4: G = (p - 2)/(p (p + 1)); solution 1 (monic, a_0 free) and solution 2 (forced integrator)
    recover the truth without noise, a_0 -> 0 in solution 1."""
    st2 = SubmodelStructure(n=1, m=1, integrators=1)
    th2 = np.array([1.0, -2.0, 1.0])
    rng = np.random.default_rng(3)
    n = 6000
    if loop == "open":
        u, y = simulate([th2], [st2], H, u=rng.standard_normal(n))
        r = c = None
    else:
        r = rng.standard_normal(n)
        u, y = simulate([th2], [st2], H, r=r, controller=(INT_CONTROLLER_NUM, INT_CONTROLLER_DEN))
        c = DiscreteController(INT_CONTROLLER_NUM, INT_CONTROLLER_DEN)
    pre = "srivc" if loop == "open" else "clsrivc"
    res2 = identify(u, y, 1 / H, [st2], [th2 * 1.05], r=r, controller=c, method=f"{pre}-uns", tol=1e-11)
    assert res2.converged, res2.message
    np.testing.assert_allclose(res2.beta, th2, rtol=1e-6)
    th1 = np.array([0.0, 1.0, -2.0, 1.0])          # monic [a0, a1, b0, b1]
    res1 = identify(u, y, 1 / H, [ST], [th1 + np.array([0.05, 0.05, 0.1, -0.05])], r=r, controller=c,
                    method=f"{pre}-uns-monic", tol=1e-11)
    assert res1.converged, res1.message
    assert abs(res1.beta[0]) < 1e-8
    np.testing.assert_allclose(res1.beta[1:], th1[1:], rtol=1e-6)


def test_unstable_methods_need_one_submodel():
    r, u, y = _data(4, 0.0, 3000)
    with pytest.raises(ValueError, match="K = 1"):
        identify(u, y, 1 / H, [MODE, MODE], [np.array([0.1, 0.5, 1.0])] * 2, method="srivc-uns")
