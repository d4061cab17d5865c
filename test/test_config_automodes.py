"""Parameters of the automatic start (issue 12): empty guesses, modes.count / max_count / frequency_range_hz."""

from __future__ import annotations

import numpy as np
import pytest

from additive_rsrivc_ros.config import MonitorConfig, ParamError, validate_params

BASE = {"loop_rate_hz": 1000.0, "closed_loop": False}


def _cfg(**kw):
    return MonitorConfig.from_params(validate_params({**BASE, **kw}))


def test_empty_guesses_mean_find_the_modes():
    cfg = _cfg(**{"modes.count": 2, "modes.frequency_range_hz": [1.0, 300.0], "modes.memory_s": [5.0]})
    assert cfg.K == 0 and cfg.auto_modes
    assert cfg.mode_count == 2 and cfg.max_mode_count == 6 and cfg.frequency_range_hz == (1.0, 300.0)
    full = cfg.with_modes(np.array([[0.0, 0.0, 2.0], [40.0, 0.02, 0.1]]), [2, 0])
    assert full.K == 2 and not full.auto_modes
    assert [m.memory_s for m in full.modes] == [5.0, 5.0]  # one memory for every mode
    assert full.modes[0].structure.integrators == 2 and full.modes[0].structure.n == 0
    assert full.modes[1].natural_frequency_hz == 40.0


def test_one_memory_or_integrator_value_applies_to_every_mode():
    cfg = _cfg(**{"modes.natural_frequency_hz": [3.0, 30.0], "modes.damping_ratio": [0.1, 0.1],
                  "modes.gain": [1.0, 1.0], "modes.memory_s": [4.0]})
    assert [m.memory_s for m in cfg.modes] == [4.0, 4.0]
    cfg = _cfg(**{"modes.natural_frequency_hz": [3.0, 30.0], "modes.damping_ratio": [0.1, 0.1],
                  "modes.gain": [1.0, 1.0]})
    assert [m.memory_s for m in cfg.modes] == [10.0, 10.0]


@pytest.mark.parametrize("kw, match", [
    ({"modes.damping_ratio": [0.1]}, "damping_ratio"),
    ({"modes.gain": [1.0]}, "gain"),
    ({"modes.natural_frequency_hz": [3.0], "modes.damping_ratio": [0.1], "modes.gain": [1.0], "modes.count": 2},
     "modes.count"),
    ({"modes.count": 7}, "max_count"),
    ({"modes.frequency_range_hz": [300.0, 10.0]}, "frequency_range_hz"),
    ({"modes.frequency_range_hz": [10.0]}, "frequency_range_hz"),
    ({"modes.frequency_range_hz": [600.0, 700.0]}, "Nyquist"),
    ({"modes.natural_frequency_hz": [3.0, 30.0], "modes.damping_ratio": [0.1, 0.1], "modes.gain": [1.0, 1.0],
      "modes.memory_s": [1.0, 2.0, 3.0]}, "memory_s"),
])
def test_inconsistent_mode_parameters_are_one_line_errors(kw, match):
    with pytest.raises(ParamError, match=match):
        _cfg(**kw)
