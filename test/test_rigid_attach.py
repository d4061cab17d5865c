"""A monitor attaches to a moving machine with a rigid body (issue 17 item 1).

The ``rigid_body`` scenario (``1/p^2`` + 8 Hz + 25 Hz under PD control, 0.5 Hz square-wave setpoint) is in motion at
every attach time. The integrator chain never forgets that initial state: before the fix the estimate diverged
(scripts/study_rigid_attach.py prints the table). Tolerance: 1 % in frequency and gain at the end, half the smallest
relevant change of a fault (faults.min_change.natural_frequency 2 %), so attaching can never raise a structural alarm
by itself; with noise std 2e-5 on a 0.1 motion the estimates' own spread is three orders of magnitude below that.
"""

from __future__ import annotations

import numpy as np
import pytest

from additive_rsrivc_ros.config import MonitorConfig
from additive_rsrivc_ros.core.estimation import kernel as kn
from additive_rsrivc_ros.core.estimation.recursive import RecursiveAdditiveSRIVC
from additive_rsrivc_ros.core.identification.offline import identify
from additive_rsrivc_ros.sim.scenarios import build

TOL_PERCENT = 1.0
ATTACH_S = (1.113, 0.113, 1.513)   # the fastest motion of the run (velocity -1.9 and +0.93) and a slow one


@pytest.fixture(scope="module")
def moving():
    return build("rigid_body", duration_s=36.0, seed=1, fault_time_s=None)


def _config(sd, *, closed_loop: bool = True, offset: float = 0.1, init_method: str = "auto") -> MonitorConfig:
    p = dict(sd.config.params)
    p["estimator.init_method"] = init_method
    p["closed_loop"] = closed_loop
    p["modes.natural_frequency_hz"] = [f * (1 + offset) for f in p["modes.natural_frequency_hz"]]
    p["modes.damping_ratio"] = [z * (1 + 2 * offset) for z in p["modes.damping_ratio"]]
    p["modes.gain"] = [g * (1 - offset) for g in p["modes.gain"]]
    return MonitorConfig.from_params(p)


def _errors(est: RecursiveAdditiveSRIVC, sd) -> np.ndarray:
    m, truth = est.modal(), sd.truth[:, -1, :]
    return np.abs(m[:, [0, 2]] - truth[:, [0, 2]]) / np.where(truth[:, [0, 2]] == 0, 1.0, truth[:, [0, 2]]) * 100


def _attach(sd, t0: float, cfg: MonitorConfig, until_s: float | None = None) -> RecursiveAdditiveSRIVC:
    """The estimator attached at ``t0``: offline initialization, then the recursion up to ``until_s`` s after
    ``t0`` (default: the end of the record)."""
    est, r, u, y = _signals_from(sd, t0, cfg)
    ni = int(cfg.init_duration_s * cfg.loop_rate_hz)
    n1 = r.size if until_s is None else int(until_s * cfg.loop_rate_hz)
    est.initialize(r[:ni], u[:ni], y[:ni])
    est.update(r[ni:n1], u[ni:n1], y[ni:n1])
    return est


def _signals_from(sd, t0: float, cfg: MonitorConfig) -> tuple[RecursiveAdditiveSRIVC, np.ndarray, np.ndarray,
                                                              np.ndarray]:
    n0 = int(round(t0 * cfg.loop_rate_hz))
    return RecursiveAdditiveSRIVC.from_config(cfg), sd.r[n0:], sd.u[n0:], sd.y[n0:]


@pytest.mark.parametrize("closed_loop", [True, False], ids=["closed", "open"])
@pytest.mark.parametrize("t0", ATTACH_S)
def test_attaching_to_a_moving_rigid_body(moving, t0, closed_loop):
    k = int(round(t0 * moving.rate_hz))
    assert abs(moving.y[k]) > 0.02 and abs(moving.y[k + 1] - moving.y[k - 1]) * moving.rate_hz / 2 > 0.1  # in motion
    est = _attach(moving, t0, _config(moving, closed_loop=closed_loop))
    assert "offline init (" in est.init_message and "rejected" not in est.init_message
    err = _errors(est, moving)
    assert np.all(err < TOL_PERCENT), (t0, err)
    assert sum(est.health.projections) == 0


def test_recursion_alone_from_the_true_model_stays_exact_when_attached_in_motion():
    """Noise-free, no offline initialization, started at the true parameters: the free response is the only thing
    the recursion does not know, and it is exact again within the first samples (before: 8 -> 3.76 Hz)."""
    sd = build("rigid_body", duration_s=25.0, seed=0, noise_std=0.0, fault_time_s=None)
    est = _attach(sd, 10.37, _config(sd, offset=0.0, init_method="none"))
    assert np.all(_errors(est, sd) < 1e-3)


def test_a_gap_restarts_the_free_response(moving):
    """After a gap the filters start from rest at a new, unknown state of the plant: estimated again."""
    cfg = _config(moving)
    est = _attach(moving, 0.113, cfg, until_s=18.7)
    _, r, u, y = _signals_from(moving, 0.113, cfg)
    est.mark_gap()
    skip = int((18.7 + 0.77) * cfg.loop_rate_hz)   # 0.77 s lost while the plant moves on
    est.update(r[skip:], u[skip:], y[skip:])
    assert np.all(_errors(est, moving) < TOL_PERCENT)
    assert sum(est.health.projections) == 0


def test_a_snapshot_without_free_response_loads_and_estimates_it(moving):
    """Version-4 state files (no free-response P block) restore: the block starts at P(0), nothing else changes."""
    cfg = _config(moving)
    est = _attach(moving, 1.113, cfg, until_s=20.0)
    _, r, u, y = _signals_from(moving, 1.113, cfg)
    nh = int(20.0 * cfg.loop_rate_hz)
    old = est.get_state()
    old["version"] = np.array([4])
    old["P"][0, 1:, 1:] = 0.0
    old["p0diag"][0, 1:] = 0.0
    back = RecursiveAdditiveSRIVC.from_config(cfg)
    back.set_state(old)
    assert np.allclose(np.diag(back.get_state()["P"][0])[1:], [kn.P0_FREE, kn.P0_FREE])
    assert np.array_equal(back.get_state()["theta"], est.get_state()["theta"])
    back.update(r[nh:], u[nh:], y[nh:])
    assert np.all(_errors(back, moving) < TOL_PERCENT)


def test_offline_fit_of_a_window_that_starts_in_motion(moving):
    """The offline additive CLSRIVC alone (the monitor's start): the integrators' free response is projected out of
    every equation (core/offline.py), so a window starting in motion fits like one starting from rest."""
    sd, cfg = moving, _config(moving)
    rate = cfg.loop_rate_hz
    out = []
    for t0 in (0.0, 1.113):
        n0, n1 = int(t0 * rate), int((t0 + cfg.init_duration_s) * rate)
        res = identify(sd.u[n0:n1], sd.y[n0:n1], rate, cfg.structures, [m.theta0() for m in cfg.modes],
                       r=sd.r[n0:n1], controller=cfg.controller, input_delay=cfg.input_delay_samples)
        assert res.converged, res.message
        truth = sd.truth[:, -1, :]
        out.append(np.max(np.abs(res.modal[:, [0, 2]] - truth[:, [0, 2]]) / truth[:, [0, 2]].clip(1e-300) * 100
                          * (truth[:, [0, 2]] > 0) + np.abs(res.modal[:, [0, 2]] - truth[:, [0, 2]]) * 100
                          * (truth[:, [0, 2]] == 0)))
    assert out[1] < TOL_PERCENT, out
