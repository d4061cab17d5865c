"""Nonparametric FRF (core/identification/frf.py) against the true ZOH frequency response of simulated plants.

Tolerances come from the reported uncertainty: for a complex Gaussian error, ``|G_hat - G|^2 / var`` is
exponentially distributed with mean 1 (F(2, 2 n_d) with the variance estimated from ``n_d`` averages:
``P(|z| > 3) = (1 + 9/n_d)^-n_d`` ~ 1e-3 at n_d = 12).
"""

from __future__ import annotations

import numpy as np
import pytest
from frf_cases import CONTROLLER, DELAY, FS, MODES

from additive_rsrivc_ros.core.identification.frf import discrete_model_frf, estimate_frf
from additive_rsrivc_ros.core.model import SubmodelStructure
from additive_rsrivc_ros.core.plant import discrete_plant, loop_margins
from additive_rsrivc_ros.sim.simulate import simulate_modes, square_wave, white_noise


def _truth(freqs: np.ndarray) -> np.ndarray:
    thetas = [np.array([2 * m.damping_ratio / (2 * np.pi * m.natural_frequency_hz),
                        1 / (2 * np.pi * m.natural_frequency_hz) ** 2, m.gain]) for m in MODES]
    return discrete_model_frf(thetas, [m.structure for m in MODES], FS, freqs, DELAY)


def _closed_loop(r: np.ndarray, noise_std: float, seed: int):
    rng = np.random.default_rng(seed)
    return simulate_modes(MODES, FS, r=r, controller=CONTROLLER, input_delay=DELAY,
                          noise=white_noise(r.size, noise_std, rng), rng=rng)


def test_controller_stabilizes_the_test_plant():
    thetas = [np.array([2 * m.damping_ratio / (2 * np.pi * m.natural_frequency_hz),
                        1 / (2 * np.pi * m.natural_frequency_hz) ** 2, m.gain]) for m in MODES]
    assert loop_margins(thetas, [m.structure for m in MODES], CONTROLLER, FS, DELAY)["max_pole"] < 1.0


@pytest.mark.parametrize("seed", [1, 2])
def test_indirect_closed_loop_frf_within_reported_variance(seed):
    rng = np.random.default_rng(100 + seed)
    r = white_noise(60 * int(FS), 0.3, rng)
    sim = _closed_loop(r, 0.01, seed)
    est = estimate_frf(sim.u, sim.y, FS, r=sim.r)
    v = est.valid
    f = est.freqs_hz
    # white reference: informative wherever the plant output stands above the noise (below 50 Hz except near the
    # anti-resonance between the modes)
    assert est.closed_loop and np.mean(v[(f > 0.5) & (f < 50.0)]) > 0.75
    assert np.all(v[((f > 4.5) & (f < 5.5)) | ((f > 39.0) & (f < 41.0))])  # the resonances are always informed
    z2 = np.abs(est.G - _truth(est.freqs_hz)) ** 2 / est.uncertainty**2
    assert np.mean(z2[v]) < 1.5  # the resolution term makes the total conservative: an upper bound only
    assert np.mean(z2[v] > 9.0) < 0.01
    # the noise-only variance alone is right away from the resonances (no resolution bias there)
    calm = v & ((f < 3) | ((f > 8) & (f < 35)) | (f > 50))
    z2n = np.abs(est.G - _truth(f)) ** 2 / est.variance
    assert 0.6 < np.mean(z2n[calm]) < 1.5


def test_noise_dominated_closed_loop_direct_is_confidently_wrong_indirect_declines():
    """Where the fed-back noise dominates u, S_yu/S_uu tends to -1/C with a small reported variance; the indirect
    estimate is not trusted there (u and y not significantly coherent with r), instead of being wrong."""
    rng = np.random.default_rng(7)
    r = white_noise(60 * int(FS), 0.01, rng)  # weak reference, strong output noise
    sim = _closed_loop(r, 0.05, 8)
    ind = estimate_frf(sim.u, sim.y, FS, r=sim.r)
    direct = estimate_frf(sim.u, sim.y, FS)  # treats u as an open-loop input
    f = ind.freqs_hz
    band = (f > 1.0) & (f < 30.0)
    assert np.mean(direct.valid[band]) > 0.9
    both = band & direct.valid
    z2_dir = np.abs(direct.G[both] - _truth(f[both])) ** 2 / direct.variance[both]
    assert np.mean(z2_dir) > 100.0
    assert np.mean(ind.valid[band]) < 0.05


def test_open_loop_h1_and_validity_follows_the_excitation():
    """Open loop through u; a band-limited input: frequencies it does not reach are not valid."""
    rng = np.random.default_rng(3)
    n = 60 * int(FS)
    from scipy import signal

    b, a = signal.butter(6, 60.0 / (FS / 2))
    u = signal.lfilter(b, a, white_noise(n, 1.0, rng))
    sim = simulate_modes(MODES, FS, u=u, input_delay=DELAY, noise=white_noise(n, 1e-3, rng), rng=rng)
    est = estimate_frf(sim.u, sim.y, FS)
    assert not est.closed_loop
    f = est.freqs_hz
    v = est.valid
    assert np.all(v[(f > 1.0) & (f < 50.0)])
    assert not np.any(v[f > 250.0])  # the 6th-order low-pass leaves < 1e-8 of the input power there
    z2 = np.abs(est.G - _truth(f)) ** 2 / est.uncertainty**2
    assert np.mean(z2[v]) < 1.5 and np.mean(z2[v] > 9.0) < 0.01
    assert est.band_hz is not None and est.band_hz[1] < 250.0


def test_square_wave_with_dither_within_uncertainty():
    """A periodic setpoint puts lines between bins: the resolution term keeps the reported uncertainty honest."""
    rng = np.random.default_rng(5)
    t = np.arange(60 * int(FS)) / FS
    r = square_wave(t, 0.5, 1.0) + white_noise(t.size, 0.05, rng)
    sim = _closed_loop(r, 0.01, 6)
    est = estimate_frf(sim.u, sim.y, FS, r=sim.r)
    v = est.valid
    z2 = np.abs(est.G - _truth(est.freqs_hz)) ** 2 / est.uncertainty**2
    assert v.sum() > 200
    assert np.mean(z2[v] > 9.0) < 0.02


@pytest.mark.parametrize("delay", [0, 1, 4])
def test_model_frf_per_submodel_equals_the_whole_plant_with_its_delay_line(delay):
    """discrete_model_frf sums each submodel's c_i (zI - Phi_i)^-1 Gamma_i and applies z^-d; the plant as one state
    space with the delay as shift states (plant.discrete_plant, 000 eq. 10) must give the same response. A lightly
    damped mode amplifies the rounding of z near its peak by ~1/(2 zeta w h) (1e4 here): hence 1e-9, not 1e-15."""
    structures = [SubmodelStructure(n=2, m=0), SubmodelStructure(n=2, m=0), SubmodelStructure(n=0, m=0, integrators=2),
                  SubmodelStructure(n=2, m=0, integrators=1)]
    wn = 2 * np.pi * np.array([33.0, 172.0, 0.0, 8.0])
    thetas = [np.array([2 * 0.004 / wn[0], 1 / wn[0] ** 2, 2.0]), np.array([2 * 0.02 / wn[1], 1 / wn[1] ** 2, 0.5]),
              np.array([0.7]), np.array([2 * 0.3 / wn[3], 1 / wn[3] ** 2, 1.5])]
    freqs = np.linspace(0.25, FS / 2 - 0.25, 3001)
    phi, gam, c = discrete_plant(thetas, structures, FS, delay)
    zs = np.exp(2j * np.pi * freqs / FS)
    whole = np.array([c @ np.linalg.solve(z * np.eye(phi.shape[0]) - phi, gam) for z in zs])
    per_submodel = discrete_model_frf(thetas, structures, FS, freqs, delay)
    assert np.max(np.abs(per_submodel - whole) / np.abs(whole)) < 1e-9


def test_bad_input_is_a_clear_error():
    with pytest.raises(ValueError, match="too short"):
        estimate_frf(np.zeros(20), np.zeros(20), FS)
    with pytest.raises(ValueError, match="finite"):
        estimate_frf(np.full(1000, np.nan), np.zeros(1000), FS)
