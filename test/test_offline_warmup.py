"""Offline identification from a record that starts with the plant in motion (free response projected out, or a
filter warm-up)."""
import numpy as np

from additive_rsrivc_ros.config import load_config
from additive_rsrivc_ros.core.identification.offline import identify, initial_transient_test, warmup_samples
from additive_rsrivc_ros.sim.plants import PAPER_MODES
from additive_rsrivc_ros.sim.simulate import simulate_modes, white_noise


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


def _fit(cfg, r, u, y, **kw):
    truth = [m.theta0() for m in cfg.modes]
    start = [th * np.array([1.05, 0.95, 1.05]) for th in truth]
    return identify(u, y, 20.0, cfg.structures, start, r=r, controller=cfg.controller, **kw)


def test_no_warmup_for_a_record_that_starts_at_rest(repo):
    """From rest the start-up transient is information (with the four sines alone it is most of it): nothing is
    left out. A record cut from the running loop starts with the plant's free response: the fit is redone with
    the model's free response projected out, on every sample."""
    cfg, r, u, y = _segment(repo, 0.0, 300.0)
    res = _fit(cfg, r, u, y)
    assert res.converged and not res.extra["initial_transient"]["detected"]
    assert res.n_samples == y.size and "warm up" not in res.message and "free_response" not in res.extra
    for start in (100.0, 123.45, 200.0):
        cfg, r, u, y = _segment(repo, start, 300.0)
        res = _fit(cfg, r, u, y)
        # detected, or the fit over every sample failed outright: either way refitted with the free response
        assert res.converged and res.extra.get("initial_transient", {"detected": True})["detected"], res.extra
        assert res.extra["free_response"] and res.n_samples == y.size and "free response" in res.message


def test_transient_test_false_alarms_on_noise_alone():
    """Under noise alone (white, and coloured like 001 §5.1, whose low-frequency level is 13x its mean) the
    statistic exceeds its 1e-3 threshold in about 1e-3 of records: 0 of 200 expected, at most 2 allowed
    (binomial tail < 2e-3). A free response of a few noise standard deviations is detected."""
    from scipy.signal import lfilter

    thetas = [np.array([0.25, 0.25, 3.0]), np.array([0.01, 0.025, 1.0])]
    from additive_rsrivc_ros.sim.independent import MODE

    rng = np.random.default_rng(3)
    n, h, window = 4000, 0.05, 800
    alarms = 0
    for k in range(200):
        e = rng.standard_normal(n)
        eps = e if k % 2 else lfilter([1.0, 0.5], [1.0, -0.85], e)
        alarms += initial_transient_test(eps, thetas, [MODE, MODE], h, window).detected
    assert alarms <= 2
    t = np.arange(n) * h
    free = 3.0 * np.exp(-t / 2.0) * np.cos(np.sqrt(3.75) * t)       # mode 1 free response, 3 noise stds
    assert initial_transient_test(free + rng.standard_normal(n), thetas, [MODE, MODE], h, window).detected


def test_record_starting_in_motion_is_unbiased(repo):
    """Mode 2 (zeta = 0.025 at 5 rad/s) rings at resonance under the sin(5t) reference when the record starts;
    filters from rest see an initial-condition transient of ~10x the input amplitude decaying over 8 s. With
    the free response projected out, every parameter is within 4 of its own reported standard deviations of the
    truth (plus 0.5 % for the finite-sample interpolation error); using every sample as if from rest biases b0 and
    zeta of mode 2 together by many standard deviations."""
    cfg, r, u, y = _segment(repo, 300.0, 900.0)
    truth = [m.theta0() for m in cfg.modes]
    start = [th * np.array([1.05, 0.95, 1.05]) for th in truth]
    res = _fit(cfg, r, u, y)
    assert res.converged and res.extra["initial_transient"]["detected"] and res.extra["free_response"]
    _within(res, truth)
    bad = identify(u, y, 20.0, cfg.structures, start, r=r, controller=cfg.controller, warmup_s=0.0)
    err = np.abs(bad.thetas[1] - truth[1])
    assert err[2] > 4 * res.theta_std[1][2] + 0.005 * truth[1][2]


def _within(res, truth, n_std: float = 4.0) -> bool:
    ok = all(np.all(np.abs(th - th0) <= n_std * std + 0.005 * np.abs(th0))
             for th, th0, std in zip(res.thetas, truth, res.theta_std, strict=True))
    assert ok, [(th, th0, std) for th, th0, std in zip(res.thetas, truth, res.theta_std, strict=True)]
    return ok


def test_a_mode_slower_than_a_quarter_of_the_record_in_motion(repo, monkeypatch):
    """60 s windows cut from the running loop: the slowest mode decays over 8 s, so five decay times (40 s) of
    warm-up exceed the quarter of the record a warm-up may take. With the free response projected out, every sample
    counts and every parameter is within 4 standard deviations (+ 0.5 %) of the truth in all four windows; with only
    the 15 s warm-up, at least one window's fit fails or is biased beyond that (measured: the one from 300 s, by
    52 standard deviations)."""
    from additive_rsrivc_ros.core.identification.offline import stable

    windows = [_segment(repo, a, a + 60.0) for a in (100.0, 123.45, 200.0, 300.0)]
    truth = [m.theta0() for m in windows[0][0].modes]
    for cfg, r, u, y in windows:
        res = _fit(cfg, r, u, y)
        assert res.converged and res.extra["free_response"] and res.n_samples == y.size
        _within(res, truth)
    monkeypatch.setattr(stable, "FREE_RESPONSE_REFIT", False)
    bad = 0
    for cfg, r, u, y in windows:
        res = _fit(cfg, r, u, y)
        assert res.extra["warmup_samples"] == y.size // 4
        try:
            bad += not (res.converged and _within(res, truth))
        except AssertionError:
            bad += 1
    assert bad >= 1


def test_a_fit_out_of_iterations_but_nearly_converged_is_tested_not_refitted(repo):
    """A fit stopped by its iteration limit while its last step moved the parameters by less than
    ``NEARLY_CONVERGED`` is a model: tested for a start in motion like a converged one. From rest it is kept as it
    stands (before, it was refitted from the guess with a warm-up: twice the cost for the order scan's short fits);
    cut from the running loop, the free response is detected and projected out in the refit. A first fit
    still moving by more than that is refitted from the guess, as before."""
    from additive_rsrivc_ros.core.identification.offline.stable import NEARLY_CONVERGED

    cfg, r, u, y = _segment(repo, 0.0, 300.0)
    res = _fit(cfg, r, u, y, max_iterations=6, tol=1e-14)
    assert not res.converged and res.extra["change_at_limit"] < NEARLY_CONVERGED
    assert not res.extra["initial_transient"]["detected"]
    assert res.n_samples == y.size and "warm up" not in res.message
    assert _fit(cfg, r, u, y, max_iterations=1, tol=1e-14, warmup_s=0.0).extra["change_at_limit"] >= NEARLY_CONVERGED
    moving = _fit(cfg, r, u, y, max_iterations=1, tol=1e-14)
    assert "the fit over every sample failed" in moving.message and moving.extra["free_response"]
    cfg, r, u, y = _segment(repo, 123.45, 300.0)
    res = _fit(cfg, r, u, y, max_iterations=6, tol=1e-14)
    assert res.extra["initial_transient"]["detected"], res.extra
    assert res.extra["free_response"] and res.n_samples == y.size and "free response" in res.message
