"""The closed loop the FRF, mode-finding and automatic-start tests share: two modes (5 Hz, 40 Hz) at 1 kHz, input
delay 2, a PI controller; and the node's params file for it without guesses."""

from __future__ import annotations

from additive_rsrivc_ros.core.controller import DiscreteController
from additive_rsrivc_ros.sim.simulate import PlantMode

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
