"""The monitor pipeline's saved state: the record :meth:`.pipeline.MonitorPipeline.get_state` writes, and the
configuration a saved state restores into, checked before anything is restored (:mod:`.saved_model`).

A partially filled initialization buffer (or search window) is not saved; modes found by the automatic start are
(``found_modes``), and count as guesses for a pipeline configured without them.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from ..diagnosis.faults import FaultMonitor, HealthMonitor
from ..estimation.estimator import MonitorSettings, RecursiveEstimator
from ..identification.autostart import FoundModes
from ..input.alignment import InvariantAligner
from ..input.input_screen import InputScreen
from ..vocabulary import plain
from .report_record import Counters, PipelineError
from .saved_model import check_model_record, model_record

STATE_VERSION = 1
SCREEN_KEYS = ("stuck", "last_y", "run_len", "run_start_t", "t_stamp_last", "clock_offset")


def state_record(*, cfg: MonitorSettings, rate: float, estimator: RecursiveEstimator | None,
                 found: FoundModes | None, faults: FaultMonitor | None, health: HealthMonitor, screen: InputScreen,
                 next_publish: float, counters: Counters, memory_s: np.ndarray, aligner: InvariantAligner | None,
                 no_model: str | None) -> dict[str, Any]:
    """Estimator (None while not estimating), found modes, baseline, fault tests, health and clock as
    JSON-serializable data."""
    est = None
    if estimator is not None:
        est = {k: plain(v) for k, v in estimator.get_state().items()}
    scr = screen.get_state()
    return {
        "version": STATE_VERSION, "K": cfg.K, "loop_rate_hz": rate,
        "model": model_record(cfg, rate),
        "estimator": est, "found_modes": None if found is None else found.to_dict(),
        "faults": None if faults is None else faults.get_state(), "health": health.get_state(),
        "pipeline": {"t0": scr["t0"], "t_last": scr["t_last"], "next_publish": next_publish,
                     "counters": counters.to_dict(), "memory_s": memory_s.tolist(),
                     **{k: scr[k] for k in SCREEN_KEYS},
                     "aligner": None if aligner is None else aligner.get_state(),
                     "magnitude": scr["magnitude"], "no_model": no_model},
    }


def restore_target(state: Mapping[str, Any], given: MonitorSettings,
                   rate: float) -> tuple[FoundModes | None, MonitorSettings]:
    """The found modes a state carries and the configuration it restores into (``given``, or ``given`` with the
    found modes when it has no guesses). Raises :class:`PipelineError` with a one-line reason when the state is for
    another version, K, rate, controller, input delay, loop or mode structures."""
    if int(state["version"]) != STATE_VERSION:
        raise PipelineError(f"saved state version {state['version']} is not {STATE_VERSION}")
    found = FoundModes.from_dict(state["found_modes"]) if state.get("found_modes") else None
    target = given            # modes found by an earlier run's automatic start count as guesses
    if found is not None and given.auto_modes:
        target = given.with_modes(found.modal, found.integrators)
    if int(state["K"]) != target.K or float(state["loop_rate_hz"]) != rate:
        raise PipelineError(f"saved state is for K={state['K']} at {state['loop_rate_hz']} Hz, the "
                            f"configuration has K={target.K or 'from the data'} at {rate} Hz")
    check_model_record(state.get("model"), model_record(target, rate))
    return found, target
