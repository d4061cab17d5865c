"""Seeded runs of the recursive estimator on the papers' plants with known truth ([RA-SRIVC] §5, §6).

Shared by ``scripts/validate_recursive.py`` (Monte Carlo tables) and the tests (test_recursive_scenarios,
test_node, test_node_names): :func:`run_paper` ([RA-SRIVC] §5, closed or open loop) and :func:`run_beam` (the flexible
beam, K = 2 of 4 modes) return RMS / worst relative modal errors against the simulated truth.
"""

from __future__ import annotations

import numpy as np

from ..core.controller import DiscreteController
from ..core.estimation.recursive import RecursiveAdditiveSRIVC
from ..core.model import SubmodelStructure, second_order_modal, theta_from_modal
from .plants import BEAM_MODES, PAPER_MODES, PAPER_PID, beam_controller
from .simulate import ModalChange, PlantMode, SimulationResult, simulate_modes, square_wave, time_vector, white_noise

#: [RA-SRIVC] §5 drifts (raised-cosine ramps): omega1 -20 % and zeta2 -50 % over [100, 300] s, omega3 -15 % and zeta3
#: -30 % over [500, 800] s
PAPER_CHANGES = [ModalChange(0, "frequency", -0.20, 100.0, 200.0, "raised_cosine"),
                 ModalChange(1, "damping", -0.50, 100.0, 200.0, "raised_cosine"),
                 ModalChange(2, "frequency", -0.15, 500.0, 300.0, "raised_cosine"),
                 ModalChange(2, "damping", -0.30, 500.0, 300.0, "raised_cosine")]
#: RMS relative error limits over [50, 1000] s, (omega, zeta, gain) in %
LIMITS = np.array([[4.5, 2.0, 0.7], [0.05, 7.5, 2.0], [1.6, 10.5, 1.3]])


def paper_reference(t: np.ndarray) -> np.ndarray:
    """[RA-SRIVC] §5 setpoint ``3 sin(0.005 t) + sin 2t + sin 5t + sin 17.5t``."""
    return 3 * np.sin(0.005 * t) + np.sin(2 * t) + np.sin(5 * t) + np.sin(17.5 * t)


def run_paper(seed: int, *, closed: bool = True, duration: float = 1000.0, spread: tuple[float, float] = (0.0, 0.02),
              lam: float = 0.999, prime_s: float = 5.0, window: tuple[float, float] = (50.0, 1000.0),
              changes: list[ModalChange] | None = None, filter_policy: str = "auto") -> dict:
    """One run of the [RA-SRIVC] §5 scenario; returns RMS relative modal errors (%) and a divergence flag.

    The start is ``theta*(0) (1 + s U)`` per parameter with ``|s| in [spread0, spread1]`` and a random sign;
    the filters are primed on the first ``prime_s`` seconds with the start model (Algorithm 2 step 1).
    """
    rng = np.random.default_rng(seed)
    rate = 20.0
    n = int(round(duration * rate))
    t = np.arange(n) / rate
    noise = 0.1 * rng.standard_normal(n)
    chg = PAPER_CHANGES if changes is None else changes
    if closed:
        sim = simulate_modes(PAPER_MODES, rate, changes=chg, r=paper_reference(t), controller=PAPER_PID, noise=noise)
    else:
        sim = simulate_modes(PAPER_MODES, rate, changes=chg, u=rng.standard_normal(n), noise=noise)
    true0 = [th[0] for th in sim.theta]
    mag = rng.uniform(spread[0], spread[1], size=(3, 3)) * rng.choice([-1.0, 1.0], size=(3, 3))
    start = [th * (1.0 + m) for th, m in zip(true0, mag, strict=True)]
    est = RecursiveAdditiveSRIVC([SubmodelStructure()] * 3, start, rate, forgetting=lam,
                                 controller=PAPER_PID if closed else None, filter_policy=filter_policy)
    n0 = int(round(prime_s * rate))
    r = sim.r if closed else None
    est.prime(None if r is None else r[:n0], sim.u[:n0], sim.y[:n0])
    tr = est.update(None if r is None else r[n0:], sim.u[n0:], sim.y[n0:], trace=True)
    th_hat = np.concatenate((np.repeat(tr[:1], n0, axis=0), tr), axis=0)  # (n, K, 3)
    a1, a2, b0 = th_hat[..., 0], th_hat[..., 1], th_hat[..., 2]
    with np.errstate(invalid="ignore", divide="ignore"):
        f_hat, z_hat = second_order_modal(a1, a2)
        w_hat = 2 * np.pi * f_hat
    truth = sim.modal  # (K, n, 3): f_hz, zeta, gain
    sel = (t >= window[0]) & (t <= window[1])
    err = np.empty((3, 3))
    for i in range(3):
        w_true = 2 * np.pi * truth[i, :, 0]
        for q, (hat, tru) in enumerate(((w_hat[:, i], w_true), (z_hat[:, i], truth[i, :, 1]),
                                        (b0[:, i], truth[i, :, 2]))):
            rel = hat[sel] / tru[sel] - 1.0
            err[i, q] = 100.0 * np.sqrt(np.mean(rel**2))
    final = np.array([[w_hat[-1, i] / (2 * np.pi * truth[i, -1, 0]) - 1.0 for i in range(3)]])
    diverged = bool(not np.all(np.isfinite(err)) or np.any(np.abs(final) > 0.2) or np.any(err > 50.0))
    return {"err": err, "diverged": diverged, "health": est.health.to_dict()}


def run_beam(seed: int, *, duration: float = 130.0, change_start: float = 40.0, change_len: float = 60.0,
             stiffness_change: float = -0.3, filter_policy: str = "auto", p0_policy: str = "information") -> dict:
    """The beam ([RA-SRIVC] §6): K = 2 of 4 modes, 4096 Hz, delay 4, memories 2.44 s / 0.244 s.

    The second mode's stiffness drops by ``stiffness_change`` (frequency ``sqrt(1 + c)``) with a raised-cosine
    profile over ``[change_start, change_start + change_len]``; 2 Hz square-wave setpoint. The controller is
    the PID of :func:`plants.beam_controller`. Returns worst relative frequency errors of mode 2 from one
    memory after the change ends (and outside the change window), and of mode 1 over the whole run after
    initialization.
    """
    rng = np.random.default_rng(seed)
    rate = 4096.0
    n = int(round(duration * rate))
    t = np.arange(n) / rate
    f_change = np.sqrt(1.0 + stiffness_change) - 1.0
    changes = [ModalChange(1, "frequency", f_change, change_start, change_len, "raised_cosine")]
    ctrl = beam_controller(rate)
    r = 1e-3 * np.sign(np.sin(2 * np.pi * 2.0 * t + 1e-9))
    noise = 2e-6 * rng.standard_normal(n)
    sim = simulate_modes(BEAM_MODES, rate, changes=changes, r=r, controller=ctrl, input_delay=4, noise=noise)
    guess = []
    for m, fac in zip(BEAM_MODES[:2], (1.1, 0.9), strict=True):
        guess.append(theta_from_modal(m.natural_frequency_hz * fac, m.damping_ratio * 1.2, m.gain * 0.9))
    lam = np.array([1.0 - 1.0 / (2.44 * rate), 1.0 - 1.0 / (0.244 * rate)])
    est = RecursiveAdditiveSRIVC([SubmodelStructure()] * 2, guess, rate, forgetting=lam, controller=ctrl,
                                 input_delay=4, filter_policy=filter_policy, p0_policy=p0_policy)
    n0 = int(5.0 * rate)
    est.initialize(r[:n0], sim.u[:n0], sim.y[:n0])
    tr = est.update(r[n0:], sim.u[n0:], sim.y[n0:], trace=True)
    f_hat = 1.0 / (2 * np.pi * np.sqrt(tr[:, :, 1]))
    tt = t[n0:]
    assert sim.modal is not None   # simulate_modes records the modal truth
    f_true = sim.modal[:2, n0:, 0].T
    rel = np.abs(f_hat / f_true - 1.0)
    after = tt >= change_start + change_len + 0.244
    before = (tt >= 10.0) & (tt <= change_start)
    return {"mode2_after": float(rel[after, 1].max()), "mode2_before": float(rel[before, 1].max()),
            "mode1": float(rel[tt >= 10.0, 0].max()), "health": est.health.to_dict(), "init": est.init_message}


#: A 4 kHz closed loop with a close pair of modes (62 / 71 Hz): the non-stationary record of ``rsrivc_identify``'s
#: stationarity test (``core/identification/stationarity.py``). PI controller (kp 0.5, ki 2), input delay 2, 0.5 Hz
# square-wave
#: setpoint with white dither.
CLOSE_PAIR_RATE_HZ = 4000.0
CLOSE_PAIR_MODES = (PlantMode(8.0, 0.05, 1.0), PlantMode(62.0, 0.02, 0.1), PlantMode(71.0, 0.02, 0.08))
CLOSE_PAIR_DELAY = 2


def close_pair_controller(rate_hz: float = CLOSE_PAIR_RATE_HZ) -> DiscreteController:
    """The PI controller of :func:`close_pair_record` (kp 0.5, ki 2, backward Euler)."""
    return DiscreteController((0.5 + 2.0 / rate_hz, -0.5), (1.0, -1.0))


def close_pair_params_yaml(extra: str = "", rate_hz: float = CLOSE_PAIR_RATE_HZ) -> str:
    """The node's params file of :func:`close_pair_record` without mode guesses (``extra``: more lines)."""
    c = close_pair_controller(rate_hz)
    return (f"additive_rsrivc_monitor:\n  ros__parameters:\n    loop_rate_hz: {rate_hz}\n"
            f"    closed_loop: true\n    controller:\n      numerator: {list(c.numerator)}\n"
            f"      denominator: {list(c.denominator)}\n    input_delay_samples: {CLOSE_PAIR_DELAY}\n"
            f"    modes:\n      memory_s: [5.0]\n    init_duration_s: 5.0\n{extra}")


def close_pair_record(seed: int, duration_s: float = 240.0, changes: tuple[ModalChange, ...] = (),
                      noise_std: float = 0.01, rate_hz: float = CLOSE_PAIR_RATE_HZ,
                      modes: tuple[PlantMode, ...] = CLOSE_PAIR_MODES) -> SimulationResult:
    """``duration_s`` of ``modes`` (default :data:`CLOSE_PAIR_MODES`) in closed loop (seeded); ``changes`` e.g. mode
    3's frequency -3 % at 120 s: ``(ModalChange(2, "frequency", -0.03, 120.0),)``."""
    rng = np.random.default_rng(seed)
    t = time_vector(rate_hz, duration_s)
    r = square_wave(t, 0.5, 1.0) + white_noise(t.size, 0.05, rng)
    return simulate_modes(modes, rate_hz, changes=list(changes), r=r, controller=close_pair_controller(rate_hz),
                          input_delay=CLOSE_PAIR_DELAY, noise=white_noise(t.size, noise_std, rng), rng=rng)
