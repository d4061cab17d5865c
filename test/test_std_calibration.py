"""The published std is calibrated on broadband data, and an invalid covariance block is flagged, never 0 (issue 17).

Coverage test: the 001 §5.2 plant (two modes, 20 Hz) in closed loop with the corrected PID (NOTES erratum 1), white
reference, white output noise, memory 25 s (5 decay times of the slower mode); known truth, stationary. The
estimation error of a forgetting estimator decorrelates over about two memory lengths (AR(1) with coefficient
lambda per sample: integrated autocorrelation time ``(1 + lam)/(1 - lam)``), so ``n_eff = T / (2 memory)`` samples of
the coverage indicator are independent; ``z^2`` decorrelates twice as fast (``(1 + lam^2)/(1 - lam^2)``). Bands are
3.5 binomial / chi-square standard deviations around the Gaussian values (P(|z| <= 2) = 0.9545, E z^2 = 1).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from additive_rsrivc_ros.core.diagnosis.faults import HealthMonitor
from additive_rsrivc_ros.core.estimation.recursive import RecursiveAdditiveSRIVC
from additive_rsrivc_ros.core.model import SubmodelStructure, modal_from_theta, theta_from_modal
from additive_rsrivc_ros.sim.plants import CL52_THETAS, PAPER_PID
from additive_rsrivc_ros.sim.simulate import PlantMode, simulate_modes

RATE = 20.0
PID = PAPER_PID
THETAS = CL52_THETAS
MODES = [PlantMode(*modal_from_theta(th)) for th in THETAS]
MEMORY_S = 25.0
NOMINAL = 0.9545
K_SD = 3.5


def _run(seed: int, duration_s: float, init_s: float = 25.0) -> tuple[np.ndarray, np.ndarray]:
    """z = (estimate - truth)/std at every second after one memory, shape (n, 2, 3); and the truth."""
    rng = np.random.default_rng(seed)
    n = int(duration_s * RATE)
    r = rng.standard_normal(n)
    sim = simulate_modes(MODES, RATE, r=r, controller=PID, noise=0.1 * rng.standard_normal(n))
    truth = np.array([[m.natural_frequency_hz, m.damping_ratio, m.gain] for m in MODES])
    guess = [theta_from_modal(f * 1.03, z * 0.9, g * 1.05) for f, z, g in truth]
    est = RecursiveAdditiveSRIVC([SubmodelStructure()] * 2, guess, RATE, forgetting=1.0 - 1.0 / (MEMORY_S * RATE),
                                 controller=PID)
    n0 = int(init_s * RATE)
    est.initialize(r[:n0], sim.u[:n0], sim.y[:n0])
    step = int(RATE)
    zs = []
    for k in range(n0, n - step + 1, step):
        est.update(r[k:k + step], sim.u[k:k + step], sim.y[k:k + step])
        if (k + step - n0) / RATE > MEMORY_S:
            m = est.modal()
            zs.append((m[:, :3] - truth) / m[:, 3:])
    return np.array(zs), truth


def test_broadband_closed_loop_std_is_calibrated() -> None:
    """Coverage of +-2 std in the issue's 90-98 % band per quantity, up to the binomial spread of n_eff samples."""
    seeds, duration = 12, 500.0
    z = np.concatenate([_run(seed, duration)[0] for seed in range(seeds)])
    assert np.all(np.isfinite(z))
    span = seeds * (duration - 25.0 - MEMORY_S)
    n_eff = span / (2.0 * MEMORY_S)
    lo = 0.90 - K_SD * math.sqrt(0.90 * 0.10 / n_eff)
    hi = 0.98 + K_SD * math.sqrt(0.98 * 0.02 / n_eff)
    coverage = np.mean(np.abs(z) <= 2.0, axis=0)          # (2, 3)
    assert np.all((coverage >= lo) & (coverage <= hi)), (coverage, lo, hi)
    # scale: E z^2 = 1 for a calibrated std, pooled over the six quantities with (at least) n_eff(z^2) = span / memory
    # samples (var z^2 = 2); sigma^2 P_bar, the former std, overstated the variance about twice (E z^2 ~ 0.6)
    mean_z2 = float(np.mean(z ** 2))
    half_z2 = K_SD * math.sqrt(2.0 / (span / MEMORY_S))
    assert abs(mean_z2 - 1.0) <= half_z2, (mean_z2, half_z2)


def _short_estimator(duration_s: float = 60.0) -> RecursiveAdditiveSRIVC:
    rng = np.random.default_rng(5)
    n = int(duration_s * RATE)
    r = rng.standard_normal(n)
    sim = simulate_modes(MODES, RATE, r=r, controller=PID, noise=0.1 * rng.standard_normal(n))
    est = RecursiveAdditiveSRIVC([SubmodelStructure()] * 2, THETAS, RATE, forgetting=1.0 - 1.0 / (MEMORY_S * RATE),
                                 controller=PID)
    est.initialize(r[:400], sim.u[:400], sim.y[:400])
    est.update(r[400:], sim.u[400:], sim.y[400:])
    return est


@pytest.mark.parametrize(("corrupt", "problem"), [("indefinite", "indefinite"), ("nan", "non-finite")])
def test_invalid_covariance_block_is_flagged_never_zero(corrupt: str, problem: str) -> None:
    est = _short_estimator()
    assert est.health.covariance_problems == ("", "")
    assert np.all(np.isfinite(est.modal()[:, 3:])) and np.all(est.modal()[:, 3:] > 0)
    st = est.get_state()
    if corrupt == "indefinite":
        # an accumulator with a negative direction: P S P^T indefinite (sqrt(max(var, 0)) would have said 0)
        w, v = np.linalg.eigh(st["S"][1])
        st["S"][1] = v @ np.diag(-np.abs(w)) @ v.T
    else:
        st["P"][1, 0, 0] = np.nan
    est.set_state(st)
    m = est.modal()
    assert np.all(np.isnan(m[1, 3:])), m[1]                  # NaN, never 0
    assert np.all(np.isfinite(m[0, 3:])) and np.all(m[0, 3:] > 0)
    health = est.health
    assert health.covariance_problems == ("", problem)
    mon = HealthMonitor([MEMORY_S, MEMORY_S])
    status = mon.assess(100.0, m, health)
    assert any("no valid uncertainty" in reason and "mode 2" in reason for reason in status.reasons)
    assert status.mode_hold(2).tolist() == [False, True]      # the mode without a valid uncertainty is held


def test_old_snapshot_without_sandwich_loads_stationary() -> None:
    """A version-3 snapshot (no S) continues with S = P^-1/(1 + lambda): std = sqrt(sigma^2 P/(1 + lambda))."""
    est = _short_estimator()
    st = est.get_state()
    del st["S"]
    est.set_state(st)
    lam = est.forgetting
    for i, (cov, info) in enumerate(zip(est.covariances, est.information_covariances, strict=True)):
        np.testing.assert_allclose(cov, info / (1.0 + lam[i]), rtol=1e-6, atol=0.0)
