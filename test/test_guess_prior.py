"""Guesses are a prior, not a requirement (issue 12 item 3): on closed-loop data that no reference line reaches at
one mode, the offline initialization keeps that mode's guessed shape (a fit of the window puts it at a wrong optimum
that only fits noise) and uses the fit for the modes the data inform."""

from __future__ import annotations

import numpy as np

from additive_rsrivc_ros.config import MonitorConfig, load_config
from additive_rsrivc_ros.core.estimation.recursive import RecursiveAdditiveSRIVC
from additive_rsrivc_ros.sim import plants
from additive_rsrivc_ros.sim.scenarios import config_dir
from additive_rsrivc_ros.sim.simulate import simulate_modes, sum_of_sines, time_vector, white_noise

OFFSET = 0.015   # guesses: frequency +1.5 %, damping +7.5 %, gain -4.5 %


def _weak_loop(seed: int):
    """000 §5 loop, reference lines at 2 and 5 rad/s (modes 1 and 2) and a weak dither: mode 3 (3.18 Hz) unreached."""
    cfg = load_config(config_dir() / "paper_example.yaml")
    rng = np.random.default_rng([seed, 12])
    t = time_vector(cfg.loop_rate_hz, cfg.init_duration_s)
    r = sum_of_sines(t, [1.0, 1.0], [2.0, 5.0]) + white_noise(t.size, 0.2, rng)
    sim = simulate_modes(plants.PAPER_MODES, cfg.loop_rate_hz, r=r, controller=cfg.controller,
                         noise=white_noise(t.size, 0.1, rng), rng=rng)
    return cfg, sim


def _start(cfg, sim, spread: float) -> RecursiveAdditiveSRIVC:
    p = dict(cfg.params)
    p["estimator.guess_spread"] = spread
    p["modes.natural_frequency_hz"] = [f * (1 + OFFSET) for f in p["modes.natural_frequency_hz"]]
    p["modes.damping_ratio"] = [z * (1 + 5 * OFFSET) for z in p["modes.damping_ratio"]]
    p["modes.gain"] = [g * (1 - 3 * OFFSET) for g in p["modes.gain"]]
    est = RecursiveAdditiveSRIVC.from_config(MonitorConfig.from_params(p))
    est.initialize(sim.r, sim.u, sim.y)
    return est


def test_unreached_mode_keeps_its_guessed_shape():
    """Over 8 noise seeds: without the prior the fit moves the unreached mode 3 beyond its guess's error in most
    (its shape only fits noise: frequency up to 11 %, damping up to 90 % off); with it, mode 3 stays within the
    guess's error (f 1.5 %, zeta 7.5 %, margins for a partly kept mode) and no mode's frequency is worse than its guess.
    """
    far, errs = 0, []
    for seed in range(8):
        cfg, sim = _weak_loop(seed)
        truth = sim.modal[:3, 0, :]
        prior = _start(cfg, sim, 0.1).modal()[:, :3] / truth - 1.0
        plain = _start(cfg, sim, 0.0).modal()[:, :3] / truth - 1.0
        far += abs(plain[2, 0]) > 2 * OFFSET or abs(plain[2, 1]) > 20 * OFFSET
        errs.append(prior)
    errs = np.abs(np.array(errs))
    assert far >= 4
    assert errs[:, 2, 0].max() <= 2 * OFFSET and errs[:, 2, 1].max() <= 10 * OFFSET, errs[:, 2]
    assert errs[:, :, 0].max() <= 2 * OFFSET, errs[:, :, 0]


def test_no_prior_for_modes_from_the_data():
    cfg = load_config(config_dir() / "paper_example.yaml")
    assert cfg.with_modes(np.array([[1.0, 0.1, 1.0]])).estimator.guess_spread == 0.0
