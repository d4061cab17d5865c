"""The closed loop the FRF, mode-finding and automatic-start tests share: two modes (5 Hz, 40 Hz) at 1 kHz, input
delay 2, a PI controller; and the node's params file for it without guesses."""

from __future__ import annotations

import numpy as np

from additive_rsrivc_ros.core.controller import DiscreteController
from additive_rsrivc_ros.sim.simulate import PlantMode, simulate_modes, square_wave, white_noise

FS = 1000.0
MODES = (PlantMode(5.0, 0.05, 1.0), PlantMode(40.0, 0.02, 0.1))
DELAY = 2
CONTROLLER = DiscreteController((0.5 + 2.0 / FS, -0.5), (1.0, -1.0))  # PI: kp 0.5, ki 2


def no_guess_params_yaml(extra: str = "") -> str:
    """The node's params file for this loop without mode guesses (the automatic start); ``extra``: more lines."""
    return f"""additive_rsrivc_monitor:
  ros__parameters:
    loop_rate_hz: {FS}
    closed_loop: true
    controller:
      numerator: {list(CONTROLLER.numerator)}
      denominator: {list(CONTROLLER.denominator)}
    input_delay_samples: {DELAY}
    modes:
      memory_s: [5.0]
    init_duration_s: 5.0
{extra}"""


def split_mode_window(path: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(r, u, y)`` of the order scan's split-mode case: 5 s cut from a running square-wave loop (seed 7, output noise
    0.01), the outputs times ``1 + path 1e-12`` (a rounding path, as another CPU's arithmetic would take)."""
    rng = np.random.default_rng(7)
    t = np.arange(int(18.0 * FS)) / FS
    r = square_wave(t, 0.5, 1.0) + white_noise(t.size, 0.05, rng)
    sim = simulate_modes(MODES, FS, r=r, controller=CONTROLLER, input_delay=DELAY,
                         noise=white_noise(t.size, 0.01, rng), rng=rng)
    w = slice(int(5.0 * FS), int(10.0 * FS))
    return sim.r[w], sim.u[w], sim.y[w] * (1.0 + path * 1e-12)
