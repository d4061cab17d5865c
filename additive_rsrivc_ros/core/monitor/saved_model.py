"""What a saved pipeline state is valid for: the loop and model structure its estimate was made under.

A state saved under another rate, loop, controller, input delay or mode structure would restore an estimate of a
different model as if it were this one; :func:`check_model_record` refuses it in one line instead.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..estimation.estimator import MonitorSettings
from .report_record import PipelineError

_LABELS = {"loop_rate_hz": "loop_rate_hz", "closed_loop": "closed_loop",
           "controller_numerator": "controller.numerator", "controller_denominator": "controller.denominator",
           "input_delay_samples": "input_delay_samples", "integrators": "modes.integrators", "orders": "mode orders"}


def model_record(cfg: MonitorSettings, rate_hz: float) -> dict[str, Any]:
    """What a saved estimate is only valid for: rate, loop structure, controller, delay, mode structures."""
    c = cfg.controller
    return {"loop_rate_hz": rate_hz, "closed_loop": bool(cfg.closed_loop),
            "controller_numerator": None if c is None else [float(v) for v in c.numerator],
            "controller_denominator": None if c is None else [float(v) for v in c.denominator],
            "input_delay_samples": int(cfg.input_delay_samples),
            "integrators": [int(s.integrators) for s in cfg.structures],
            "orders": [[int(s.n), int(s.m)] for s in cfg.structures]}


def check_model_record(saved: Any, mine: dict[str, Any]) -> None:
    """Refuse (one line) a state saved under another model: another controller, delay, loop or structures."""
    if not isinstance(saved, dict):
        raise PipelineError("saved state does not record its controller, input delay and mode structures "
                            "(saved by an older version); not restored")
    for key, label in _LABELS.items():
        if key not in saved:
            raise PipelineError(f"saved state does not record {label}; not restored")
        a, b = saved[key], mine[key]
        same = (a is None) == (b is None) and (a is None or np.array_equal(np.asarray(a, dtype=float),
                                                                           np.asarray(b, dtype=float)))
        if not same:
            raise PipelineError(f"saved state is for {label} {a}, the configuration has {b}; not restored")
