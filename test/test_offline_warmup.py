"""Offline identification from a record that starts with the plant in motion (filter warm-up)."""
import numpy as np

from additive_rsrivc_ros.config import load_config
from additive_rsrivc_ros.core.offline import identify, starts_at_rest, warmup_samples
from additive_rsrivc_ros.core.scenarios import PAPER_MODES
from additive_rsrivc_ros.core.simulate import simulate_modes, white_noise


def _segment(repo, start_s: float, end_s: float):
    cfg = load_config(repo / "config" / "paper_example.yaml")
    rng = np.random.default_rng(7)
    rate = cfg.loop_rate_hz
    t = np.arange(int(end_s * rate)) / rate
    r = 3 * np.sin(0.005 * t) + np.sin(2 * t) + np.sin(5 * t) + np.sin(17.5 * t) + white_noise(t.size, 1.0, rng)
    sim = simulate_modes(PAPER_MODES, rate, r=r, controller=cfg.controller, noise=white_noise(t.size, 0.1, rng),
                         rng=rng)
    a = int(start_s * rate)
    return cfg, sim.r[a:], sim.u[a:], sim.y[a:]


def test_default_warmup_is_five_decay_times_of_the_slowest_mode(repo):
    cfg = load_config(repo / "config" / "paper_example.yaml")
    thetas = [m.theta0() for m in cfg.modes]
    # slowest mode: 0.5/(0.04 p^2 + 0.01 p + 1), decay time 2 a2 / a1 = 8 s -> 40 s at 20 Hz
    assert warmup_samples(thetas, cfg.structures, 20.0, 100000) == 800
    assert warmup_samples(thetas, cfg.structures, 20.0, 1000) == 250  # at most a quarter of the record
    assert warmup_samples(thetas, cfg.structures, 20.0, 1000, warmup_s=0.0) == 0


def test_no_warmup_for_a_record_that_starts_at_rest(repo):
    """From rest the start-up transient is information (with the four sines alone it is most of it): nothing is
    left out. A record cut from the running loop starts with a value or a slope well above the noise floor."""
    cfg, r, u, y = _segment(repo, 0.0, 300.0)
    assert starts_at_rest(y)
    thetas = [m.theta0() for m in cfg.modes]
    assert warmup_samples(thetas, cfg.structures, 20.0, y.size, y=y) == 0
    for start in (100.0, 123.45, 200.0):
        _, _, _, y_cut = _segment(repo, start, 300.0)
        assert not starts_at_rest(y_cut)
        assert warmup_samples(thetas, cfg.structures, 20.0, y_cut.size, y=y_cut) == min(800, y_cut.size // 4)


def test_record_starting_in_motion_is_unbiased_with_warmup(repo):
    """Mode 2 (zeta = 0.025 at 5 rad/s) rings at resonance under the sin(5t) reference when the record starts;
    filters from rest see an initial-condition transient of ~10x the input amplitude decaying over 8 s. With
    the warm-up left out, every parameter is within 4 of its own reported standard deviations of the truth
    (plus 0.5 % for the finite-sample interpolation error); using every sample biases b0 and zeta of mode 2
    together by many standard deviations."""
    cfg, r, u, y = _segment(repo, 300.0, 900.0)
    truth = [m.theta0() for m in cfg.modes]
    start = [th * np.array([1.05, 0.95, 1.05]) for th in truth]
    res = identify(u, y, 20.0, cfg.structures, start, r=r, controller=cfg.controller)
    assert res.converged
    for th, th0, std in zip(res.thetas, truth, res.theta_std, strict=True):
        assert np.all(np.abs(th - th0) <= 4 * std + 0.005 * np.abs(th0)), (th, th0, std)
    bad = identify(u, y, 20.0, cfg.structures, start, r=r, controller=cfg.controller, warmup_s=0.0)
    err = np.abs(bad.thetas[1] - truth[1])
    assert err[2] > 4 * res.theta_std[1][2] + 0.005 * truth[1][2]
