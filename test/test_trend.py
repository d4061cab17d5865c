"""core/diagnosis/trend.py: per-bag levels and the drift test across recordings, on synthetic data with known truth."""

from __future__ import annotations

import math

import numpy as np
import pytest

from additive_rsrivc_ros.core.diagnosis.trend import (
    MIN_RECORDINGS,
    bag_level,
    drift_test,
    fleet_drift,
    time_average_variance_ratio,
)


def test_bag_level_uses_monitored_estimates_and_their_correlation_time() -> None:
    rng = np.random.default_rng(0)
    n, k = 400, 2                                        # 40 s at 10 Hz
    modal = np.zeros((n, k, 6))
    modal[:, :, 0] = [5.0, 20.0]
    modal[:, :, 1] = [0.05, 0.02]
    modal[:, :, 2] = [1.0, 0.2]
    modal[:, :, :3] *= 1 + 1e-3 * rng.standard_normal((n, k, 3))
    modal[:, :, 3:] = 1e-6                               # published std far below the actual scatter
    monitored = np.arange(n) >= 100
    modal[:100, 1, 0] = 30.0                             # the start-up transient must not count
    lv = bag_level(modal, monitored, [1.0, 3.0], 0.1)
    assert lv is not None and lv.monitored_s == pytest.approx(30.0)
    np.testing.assert_allclose(lv.value[:, 0], [5.0, 20.0], rtol=5e-4)
    g = [2 * (x - 1 + math.exp(-x)) / x**2 for x in (30.0, 10.0)]       # time average over T of exp(-|t|/T_m)
    np.testing.assert_allclose(lv.n_eff, [1 / g[0], 1 / g[1]])          # ~ T / (2 memory) for T >> memory
    # se from the actual scatter (1e-3 relative), not from the published 1e-6
    # (independent values here: the median's efficiency sqrt(pi/2) instead of the correlated sqrt(pi ln2 / 2))
    expected = math.sqrt(math.pi * math.log(2) / 2) * 1e-3 * 20.0 * math.sqrt(g[1] / (1 - g[1]))
    assert lv.std[1, 0] == pytest.approx(expected, rel=0.15)
    assert bag_level(modal, np.zeros(n, bool), [1.0, 3.0], 0.1) is None


def test_time_average_variance_ratio_limits() -> None:
    x = np.array([0.0, 1e-6, 1.0, 3.0, 1e4])
    g = time_average_variance_ratio(x)
    assert g[0] == pytest.approx(1.0) and g[1] == pytest.approx(1.0, abs=1e-6)
    assert g[2] == pytest.approx(2 * math.exp(-1.0)) and g[4] == pytest.approx(2e-4, rel=1e-3)
    assert np.all(np.diff(g) < 0)


def test_bag_level_std_is_calibrated_on_short_autocorrelated_records() -> None:
    """A settled part of only 3 memory lengths of an AR(1) estimate (correlation exp(-dt/T_m) between output
    instants, as a recursive estimate with forgetting memory T_m): the level's standard error must match the
    actual spread of the level over many records (neither the iid formula, ~5x too small here, nor 10x more)."""
    rng = np.random.default_rng(5)
    memory, period, n, runs, sigma = 2.0, 0.1, 60, 800, 0.01
    rho = math.exp(-period / memory)
    e = rng.standard_normal((runs, n))
    x = np.empty((runs, n))
    x[:, 0] = e[:, 0]
    for j in range(1, n):
        x[:, j] = rho * x[:, j - 1] + math.sqrt(1 - rho**2) * e[:, j]
    levels, ses = [], []
    for r in range(runs):
        modal = np.zeros((n, 1, 6))
        modal[:, 0, 0] = 60.0 + sigma * x[r]
        modal[:, 0, 1], modal[:, 0, 2] = 0.02, 0.1
        modal[:, 0, 3] = sigma                           # the estimator's own (delta-method) std
        modal[:, 0, 4:] = 1e-6
        lv = bag_level(modal, np.ones(n, bool), [memory], period)
        levels.append(lv.value[0, 0])
        ses.append(lv.std[0, 0])
    ratio = float(np.mean(ses)) / float(np.std(levels, ddof=1))
    # the empirical std of 800 levels is itself uncertain by ~2.5 % (x 3 = 7.5 %); the level's std takes the larger
    # of two estimates of the scatter (its own MAD, the published std), which errs on the safe side
    assert 0.92 <= ratio <= 1.25, ratio


def test_linear_drift_is_flagged_with_direction_and_first_recording() -> None:
    x = np.arange(6)
    y = 20.0 * (1 - 0.005 * x)
    se = np.full(6, 0.002)
    res = drift_test(x, y + np.random.default_rng(1).normal(0, 0.002, 6), se, min_change=0.0175, spread_factor=3.0,
                     alpha=0.01 / 6)
    assert res.flagged and res.direction == "down"
    assert res.first_index == 4                          # -2.0 % at x = 4, -1.5 % at x = 3
    assert res.change_percent == pytest.approx(-2.5, abs=4 * res.change_std_percent)


def test_significant_but_irrelevant_change_is_not_flagged() -> None:
    x = np.arange(8)
    y = 20.0 * (1 + 0.001 * x)                           # +0.7 %: far below faults.min_change (2 %)
    res = drift_test(x, y, np.full(8, 1e-4), min_change=0.02, spread_factor=3.0, alpha=0.01)
    assert res.p_value < 1e-6 and not res.flagged and "below the relevant" in res.reason


def test_too_few_recordings_give_no_test() -> None:
    res = drift_test(np.arange(MIN_RECORDINGS - 1), [1.0, 0.5, 0.1], [0.01] * 3, min_change=0.02,
                     spread_factor=3.0, alpha=0.01)
    assert not res.flagged and "needed" in res.reason


def test_false_alarm_rate_with_recording_to_recording_variation() -> None:
    """Healthy machine, levels vary between recordings 10x more than each bag's standard error says (the
    estimator's bias differs per recording): the random-effects test keeps its level. Thresholds at 0 so that
    only the significance test decides."""
    rng = np.random.default_rng(2)
    alpha, runs = 0.05, 2000
    x = np.arange(6)
    se = np.full(6, 1e-4)
    alarms = sum(drift_test(x, 20.0 + rng.normal(0, 1e-3, 6), se, min_change=0.0, spread_factor=0.0,
                            alpha=alpha).flagged for _ in range(runs))
    # binomial: mean alpha * runs = 100, std ~ 9.7; allow 3 std above
    assert alarms <= alpha * runs + 3 * math.sqrt(runs * alpha * (1 - alpha)), alarms


def test_fleet_drift_skips_excluded_recordings_and_keeps_their_place() -> None:
    from additive_rsrivc_ros.core.diagnosis.trend import BagLevel

    def lv(f2: float) -> BagLevel:
        return BagLevel(np.array([[5.0, 0.05, 1.0], [f2, 0.02, 0.2]]), np.full((2, 3), 1e-4), 3.0, np.ones(2))

    levels = [lv(20.0 * (1 - 0.01 * j)) if j != 2 else None for j in range(6)]
    tests = fleet_drift(levels, {"natural_frequency": 0.02, "damping": 0.2, "gain": 0.1}, spread_factor=3.0)
    assert len(tests) == 6
    (hit,) = [t for t in tests if t.flagged]
    assert (hit.mode, hit.quantity, hit.direction) == (2, "natural_frequency", "down")
    assert hit.indices == [0, 1, 3, 4, 5] and hit.first_index == 3       # -3 % at position 3 (2 is excluded)
    assert hit.alpha == pytest.approx(0.01 / 6)
