"""CI-sized 000 §5 scenario (issue 4 verification): fewer seeds than scripts/validate_recursive.py.

Same assertion kind as the Monte Carlo script: no divergence and the mean RMS relative error over
[50, 1000] s within the issue's limits (1.25x an independent implementation), closed loop, lambda 0.999,
start +-2 %. The issue's limits are for a 10-seed mean; with 4 seeds the mean is compared with the limit
plus two standard errors of the mean (sample spread over the seeds / sqrt(4)), the statistical allowance for
the smaller sample (per seed, the mode-3 gain error ranges about 0.5-2 %).
"""
from pathlib import Path

import numpy as np

from additive_rsrivc_ros.sim.experiments import LIMITS, run_paper


def test_paper_example_closed_loop_ci():
    runs = [run_paper(seed) for seed in range(4)]
    assert not any(r["diverged"] for r in runs)
    errs = np.array([r["err"] for r in runs])
    mean, sem = errs.mean(axis=0), errs.std(axis=0, ddof=1) / np.sqrt(len(runs))
    assert np.all(mean <= LIMITS + 2 * sem), np.round(mean, 3)


def test_paper_example_open_loop_far_start_converges():
    """Starts 10-20 % off converge: after the last ramp the errors are within the issue's limits."""
    runs = [run_paper(seed, closed=False, spread=(0.10, 0.20), window=(850.0, 1000.0)) for seed in range(3)]
    assert not any(r["diverged"] for r in runs)
    mean = np.mean([r["err"] for r in runs], axis=0)
    assert np.all(mean <= LIMITS), np.round(mean, 3)


def test_auto_filter_policy_selects_only_modes_with_memory_below_their_decay_time():
    """Beam: mode 2's memory 0.244 s < 3 x its decay time 2 a2/a1 = 0.28 s -> smoothed (one period, 30 ms);
    mode 1 (memory 2.44 s, decay 0.21 s) and every mode of the 000 §5 example (memory 50 s, decay <= 8 s) keep
    Algorithm 2 as printed. A runtime memory change re-evaluates the choice."""
    from additive_rsrivc_ros.config import load_config
    from additive_rsrivc_ros.core.estimation.recursive import RecursiveAdditiveSRIVC

    repo = Path(__file__).resolve().parents[1]
    beam = RecursiveAdditiveSRIVC.from_config(load_config(repo / "config" / "beam.yaml"))
    fm = beam.filter_memory_s
    assert fm[0] == 0.0
    assert abs(fm[1] - 1.0 / 32.97) < 2e-3  # one period of the 33 Hz mode
    beam.set_memory([2.44, 2.0])  # longer than 3 decay times: back to Algorithm 2
    assert np.all(beam.filter_memory_s == 0.0)
    paper = RecursiveAdditiveSRIVC.from_config(load_config(repo / "config" / "paper_example.yaml"))
    assert np.all(paper.filter_memory_s == 0.0)


def test_beam_short_memory_with_filter_model():
    """000 §6 beam with the paper's memories [2.44, 0.244] s (lambda2 = 0.999): mode 2's memory is below its
    decay time 1/(zeta omega) = 0.28 s, where Algorithm 2's estimate <-> prefilter loop breaks down
    (scripts/study_short_memory.py). With the filter model (auto policy: mode 2 only) the issue's targets hold over
    the whole run after 10 s, including the -10 % frequency drift: mode 2 within 2 %, mode 1 within 1 %, the
    damping never collapses (within 10 % of a zeta of 0.017, i.e. far from the zeta -> 0 breakdown), no
    projections."""
    from additive_rsrivc_ros.core.estimation.recursive import RecursiveAdditiveSRIVC
    from additive_rsrivc_ros.core.model import modal_from_theta
    from additive_rsrivc_ros.sim import scenarios

    sc = scenarios.build("beam", seed=4)  # the worst of seeds 0-4 with Algorithm 2 (f2 error 95 %)
    cfg = sc.config
    rate = cfg.loop_rate_hz
    assert [m.memory_s for m in cfg.modes] == [2.44, 0.244]  # the paper's lambda = 0.9999, 0.999 at 4096 Hz
    est = RecursiveAdditiveSRIVC.from_config(cfg)  # the shipped path: estimator.filter_smoothing = auto
    n0 = int(4 * rate)
    est.initialize(sc.r[:n0], sc.u[:n0], sc.y[:n0])
    tr = est.update(sc.r[n0:], sc.u[n0:], sc.y[n0:], trace=True)
    k = np.arange(int(10 * rate) - n0, tr.shape[0], 64)
    modal = np.array([[modal_from_theta(tr[j, i]) for i in range(2)] for j in k])
    rel = modal / np.transpose(sc.truth[:, k + n0, :], (1, 0, 2)) - 1.0
    assert np.max(np.abs(rel[:, 1, 0])) < 0.02
    assert np.max(np.abs(rel[:, 0, 0])) < 0.01
    assert np.max(np.abs(rel[:, 1, 1])) < 0.10
    assert est.health.projections == (0, 0)
