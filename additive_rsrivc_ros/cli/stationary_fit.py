"""``rsrivc_identify``'s fit of a record that may not be stationary (:mod:`..core.stationarity`).

The modes are found (``--modes``, or a params file without guesses) on the record's first segment when the record is
long enough to be tested, else on all of it: a record whose plant changed later would otherwise be fitted with one
mode split in two. Then the segments are compared, and the whole record (stationary) or its longest stationary part
is fitted; the JSON gains ``stationarity`` (:meth:`..core.stationarity.Stationarity.to_dict`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import numpy as np

    from ..config import MonitorConfig
    from ..core.identification.offline import IdentificationResult
    from ..core.identification.stationarity import Stationarity
    from ..io.bagio import Signals


@dataclass
class RecordFit:
    """The fit to report, the samples it used (indices into the record), the modes found and the test."""

    cfg: MonitorConfig
    result: IdentificationResult
    index: np.ndarray
    found: Any
    stationarity: Stationarity
    split: list[tuple[int, int]]
    span_s: list[float]          # [first, last + one period] of the samples fitted


MODE_FINDING_S = 60.0   # a record long enough to be tested: its modes are found on its first minute (or segment)


def _find_modes(sig: Signals, k: np.ndarray, cfg: MonitorConfig, modes: int | None) -> tuple[MonitorConfig, Any]:
    """The modes found on the record's first :data:`MODE_FINDING_S` (at least its first segment) when it is long
    enough to be tested for stationarity, else on all of it: a plant that changed later does not enter them.
    Found one mode split in two (the window held a change), they are found again on the window's first half."""
    from ..core.identification.modefind import autostart_config
    from ..core.identification.stationarity import MAX_SEGMENTS, MIN_SEGMENT_S, split_pairs

    rate = cfg.loop_rate_hz
    r = sig.r if cfg.closed_loop else None
    pieces = min(MAX_SEGMENTS, int(k.size // (MIN_SEGMENT_S * rate)))
    n = k.size if pieces < 2 else min(k.size, max(int(MODE_FINDING_S * rate), k.size // pieces))
    while True:
        w = k[:n]
        new, found = autostart_config(cfg, None if r is None else r[w], sig.u[w], sig.y[w], modes)
        if n == k.size or found.identification is None or not split_pairs(found.identification) \
                or n // 2 < MIN_SEGMENT_S * rate:
            return new, found
        n //= 2


def fit_record(sig: Signals, k: np.ndarray, cfg: MonitorConfig, modes: int | None, method: str, iters: int,
               tol: float) -> RecordFit:
    """Find the modes if asked, test the screened samples ``sig[k]`` (contiguous) for stationarity and fit the
    whole of them or their longest stationary part."""
    from ..core.diagnosis.faults import FaultSettings
    from ..core.identification.offline import identify
    from ..core.identification.stationarity import identify_segments, split_pairs
    from .atomic import raise_if_interrupted

    closed = cfg.closed_loop
    rate = cfg.loop_rate_hz
    r = sig.r if closed else None
    found = None
    if cfg.auto_modes or modes is not None:
        cfg, found = _find_modes(sig, k, cfg, modes)
    controller = cfg.controller if closed else None

    def run_fit(sl: Any, start: Any, warmup_s: float | None = None) -> IdentificationResult:
        return identify(sig.u[sl], sig.y[sl], rate, cfg.structures, start, r=None if r is None else r[sl],
                        controller=controller, input_delay=cfg.input_delay_samples, method=method,
                        max_iterations=iters, tol=tol, projection=cfg.estimator.stability_projection,
                        warmup_s=warmup_s)

    def fit(a: int, b: int, warm: int | None, start: Any) -> IdentificationResult | None:
        sl = k[(a - (warm or 0)) if a else 0:b]
        try:
            return run_fit(sl, start, None if warm is None else warm / rate)
        except ValueError:       # e.g. the start does not stabilize this part's loop: the part is not usable
            return None
        finally:
            raise_if_interrupted()

    settings = FaultSettings.from_params(cfg.params)
    min_change = list(settings.min_change)      # (natural frequency, damping, gain)
    thetas0 = [m.theta0() for m in cfg.modes]
    st, part, start = identify_segments(fit, k.size, rate, thetas0, cfg.structures, min_change, float(sig.t[k[0]]))
    if part is not None and part.result is not None:
        res, index = part.result, k[part.a:part.b]
    else:
        res = run_fit(k, start)
        index = k
    span = [float(sig.t[index[0]]), float(sig.t[index[-1]]) + 1.0 / rate]
    return RecordFit(cfg, res, index, found, st, split_pairs(res), span)


def add_stationarity(doc: dict[str, Any], fitted: RecordFit) -> None:
    """JSON keys ``stationary`` (true, false or null: not tested), ``stationarity`` (the test), ``fitted_s`` (the
    samples the result is fitted on) and, for a mode split in two, ``split_modes`` with ``converged`` false."""
    st = fitted.stationarity
    doc["stationary"] = st.stationary
    doc["stationarity"] = st.to_dict()
    part = st.runs[st.chosen] if st.runs and st.chosen >= 0 else None
    doc["fitted_s"] = [part.start_s, part.end_s] if part is not None else fitted.span_s
    if fitted.split:
        m = fitted.result.modal
        pairs = "; ".join(f"modes {i} and {j} at {m[i - 1][0]:.5g} / {m[j - 1][0]:.5g} Hz with gains "
                          f"{m[i - 1][2]:.3g} / {m[j - 1][2]:.3g}" for i, j in fitted.split)
        doc["split_modes"] = [list(p) for p in fitted.split]
        doc["converged"] = False
        doc["message"] = (f"{doc.get('message') or ''}; one mode split in two ({pairs}): not a result; fit fewer "
                          "modes or a stationary part (--start/--end)").lstrip("; ")
