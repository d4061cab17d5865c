"""Offline (batch) identification of a rosbag2's modes with the monitor's params file (docs/INTERFACE.md).

``rsrivc_identify BAG --params-file YAML --out FILE.json [--method NAME]``: the guesses (``modes.*``), controller, input
delay and ``closed_loop`` come from the params file; the JSON object (``method``, ``converged``, ``iterations``,
``modes`` with ``theta`` in [RA-SRIVC] eq. 7 order and the modal values with their std, ``residual_variance``, ...) is
described in docs/INTERFACE.md. Exit status 0 on success (also when not converged), 2 with one line on bad input.
``--modes K|auto`` (or a params file without guesses) first finds the modes from the data
(``core/identification/modefind.py``; the
JSON gains ``frf``, ``order_selection``, ``mode_finding``); ``--out-params FILE.yaml`` writes a complete params file for
the node (``--baseline`` adds ``faults.baseline.*``). In closed loop the record first goes through the stream aligner
(``core/input/alignment.py``), then the screening (``core/input/screening.py``).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..core.vocabulary import BASELINE_KEYS, json_clean
from ..process_exit import console_entry
from .atomic import Interrupted, atomic_write_text, exit_code, interrupts, raise_if_interrupted, received
from .parser import OneLineParser
from .timerange import add_range_arguments, range_of

if TYPE_CHECKING:   # the numerical modules are imported inside the functions: SIGINT/SIGTERM handling comes first
    import numpy as np

    from ..config import MonitorConfig
    from ..core.diagnosis.faults import FaultSettings
    from ..core.input.screening import Screening
    from ..io.bagio import Signals


def _cli_methods() -> tuple[str, ...]:
    from ..core.identification.offline import METHODS

    return tuple(m for m in METHODS if not m.endswith("-monic"))


def _parser() -> argparse.ArgumentParser:
    ap = OneLineParser(prog="rsrivc_identify", description=__doc__.split("\n\n")[0])
    ap.add_argument("bag", help="rosbag2 directory (mcap or sqlite3)")
    ap.add_argument("--params-file", required=True, help="params YAML of the monitor node")
    ap.add_argument("--out", required=True, help="output JSON file")
    ap.add_argument("--method", default="auto", choices=_cli_methods(),
                    help="estimator (auto: additive-clsrivc in closed loop, additive-srivc in open loop)")
    ap.add_argument("--max-iterations", type=int, default=None,
                    help="iteration limit (default: estimator.init_max_iterations of the params file, at least 50)")
    ap.add_argument("--tol", type=float, default=1e-7, help="relative-change tolerance (default 1e-7)")
    ap.add_argument("--node-name", default=None, help="node name of the params file section")
    ap.add_argument("--modes", default=None, type=_modes_arg, metavar="K|auto",
                    help="find the modes from the data (K of them, or their number by held-out output error) instead "
                         "of starting from the guesses; default: only when the params file has no guesses")
    ap.add_argument("--out-params", default=None, metavar="FILE.yaml",
                    help="write a complete params file for the node with the identified modes.*")
    ap.add_argument("--baseline", action="store_true",
                    help="with --out-params: also write the identified values as faults.baseline.*")
    add_range_arguments(ap)
    return ap


def _modes_arg(text: str) -> int:
    """``auto`` -> 0, else a positive integer."""
    if text.strip().lower() == "auto":
        return 0
    try:
        k = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--modes must be a positive integer or 'auto', got {text!r}") from None
    if k < 1:
        raise argparse.ArgumentTypeError(f"--modes must be a positive integer or 'auto', got {text!r}")
    return k


def longest_gap_free(t: np.ndarray, rate_hz: float, tolerance: float) -> tuple[slice, int]:
    """Longest run of samples spaced by at most ``(1 + tolerance)/rate_hz`` and the number of gaps in ``t`` (the
    gap rule of the pipeline, ``faults.health.gap_tolerance``)."""
    import numpy as np

    if t.size < 2:
        return slice(0, t.size), 0
    breaks = np.flatnonzero(np.diff(t) > (1.0 + tolerance) / rate_hz) + 1
    edges = np.concatenate(([0], breaks, [t.size]))
    k = int(np.argmax(np.diff(edges)))
    return slice(int(edges[k]), int(edges[k + 1])), int(breaks.size)


def _by(counts: dict[str, int]) -> str:
    return ", ".join(f"{k}: {v}" for k, v in counts.items() if v)


def screen_record(sig: Signals, cfg: MonitorConfig, settings: FaultSettings, warn: Callable[[str], None]) -> Screening:
    """Screen the bag's samples (:func:`..core.screening.screen`), one warning line per category of bad samples;
    raise ``ValueError`` (one line) when no clean stretch long enough for a fit is left."""
    import numpy as np

    from ..core.input.screening import ABSURD_ABS, ABSURD_REL, screen

    signals = {"reference": sig.r if cfg.closed_loop else None, "input": sig.u, "output": sig.y}
    sc = screen(sig.t, signals, cfg.loop_rate_hz, settings.health_gap_tolerance,
                held_is_missing=settings.health_repeated_output_is_missing)
    if sc.duplicates:
        warn(f"{sc.duplicates} duplicate time stamp(s): the later sample of each pair dropped")
    if sc.out_of_order:
        warn(f"{sc.out_of_order} out-of-order time stamp(s) dropped")
    if sc.nonfinite:
        warn(f"{sum(sc.nonfinite.values())} non-finite sample(s) ({_by(sc.nonfinite)}) excluded")
    if sc.absurd:
        warn(f"{sum(sc.absurd.values())} sample(s) of absurd magnitude ({_by(sc.absurd)}; |x| > {ABSURD_ABS:g} or "
             f"more than {ABSURD_REL:g} robust scales from the median) excluded")
    if sc.held:
        warn(f"{sc.held} held output sample(s) (output exactly equal to the previous one: a lost sample repeated by "
             "the receiver; faults.health.repeated_output_is_missing) excluded")
    n_min = max(int(np.ceil(cfg.init_duration_s * cfg.loop_rate_hz)), 50)
    if sc.held > settings.health_max_repeated_fraction * max(sig.n, 1) and sc.used < n_min:
        raise ValueError(f"the output repeats its previous value in {sc.held} of {sig.n} samples (a quantized or "
                         "held sensor?); set faults.health.repeated_output_is_missing: false to use them as data")
    if sc.used < n_min:
        raise ValueError(f"no clean stretch long enough to fit: the longest run of valid, evenly spaced samples has "
                         f"{sc.used} samples, at least {n_min} (init_duration_s) needed")
    if sc.used < sc.n - sc.duplicates - sc.out_of_order:
        t_a, t_b = float(sig.t[sc.index[0]]), float(sig.t[sc.index[-1]])
        n_bad = sc.held + sum(sc.nonfinite.values()) + sum(sc.absurd.values())
        why = " and ".join(w for w, c in ((f"{sc.gaps} data gap(s)", sc.gaps), (f"{n_bad} bad sample(s)", n_bad)) if c)
        warn(f"the record splits into {sc.pieces} clean segment(s) at {why}; the filters need evenly spaced valid "
             f"samples, so only the longest gap-free segment without bad samples [{t_a:.6g}, {t_b:.6g}] s "
             f"({sc.used} of {sig.n} samples) is used")
    return sc


def write_params_file(cfg: MonitorConfig, doc: dict, path: str, node_name: str | None, baseline: bool,
                      source: str) -> None:
    """The input params with the identified ``modes.*`` (and ``faults.baseline.*`` when ``baseline``) as a complete,
    commented params YAML for the node, written atomically."""
    import numpy as np

    from ..config import DEFAULT_NODE_NAME, render_params_yaml

    p = dict(cfg.params)
    modes = doc["modes"]
    for key in BASELINE_KEYS:
        vals = [m[key] for m in modes]
        if any(v is None or not np.isfinite(v) for v in vals):
            raise ValueError(f"identified {key} is not finite: no params file written")
        p[f"modes.{key}"] = [float(v) for v in vals]
        if baseline:
            p[f"faults.baseline.{key}"] = [float(v) for v in vals]
            stds = [m.get(f"{key}_std") for m in modes]
            p[f"faults.baseline.{key}_std"] = ([float(v) for v in stds]
                                               if all(v is not None and np.isfinite(v) for v in stds) else [])
    p["modes.integrators"] = [int(s.integrators) for s in cfg.structures]
    p["modes.count"] = 0
    header = (f"Written by rsrivc_identify from {source}: the input params with the identified modes.*"
              + (" and faults.baseline.*" if baseline else "") + f".\nmethod {doc['method']}, converged "
              f"{doc['converged']}, residual variance {doc['residual_variance']}.")
    text = render_params_yaml(p, node_name or DEFAULT_NODE_NAME, header)
    out_path = Path(path)
    if out_path.parent and not out_path.parent.exists():
        raise ValueError(f"output directory {out_path.parent} does not exist")
    atomic_write_text(out_path, text)

def run(bag: str, params_file: str, out: str, method: str = "auto", max_iterations: int | None = None,
        tol: float = 1e-7, node_name: str | None = None, warn: Callable[[str], None] | None = None,
        modes: int | None = None, out_params: str | None = None, baseline: bool = False,
        start: str | float | None = None, end: str | float | None = None) -> dict:
    """Identify the bag and write the JSON (strict: non-finite numbers as null, written all-or-nothing); returns
    the JSON object. Raises ``ValueError`` on bad input. Bad samples are excluded, each category with one
    warning line (``warn``, default stderr), never fitted over."""
    from ..config import load_config
    from ..core.diagnosis.faults import FaultSettings
    from ..io.bagio import read_signals
    from .stationary_fit import add_stationarity, fit_record

    warn = warn or (lambda m: print(f"rsrivc_identify: warning: {m}", file=sys.stderr))
    cfg = load_config(params_file) if node_name is None else load_config(params_file, node_name)
    out_path = Path(out)
    if out_path.parent and not out_path.parent.exists():
        raise ValueError(f"output directory {out_path.parent} does not exist")
    closed = cfg.closed_loop
    if baseline and not out_params:
        raise ValueError("--baseline needs --out-params")
    if method in ("additive-clsrivc", "clsrivc", "clsrivc-uns") and not closed:
        raise ValueError(f"method {method} needs closed-loop data (closed_loop: true and a controller)")
    iters = max_iterations if max_iterations is not None else max(50, cfg.estimator.init_max_iterations)
    if iters < 1:
        raise ValueError("--max-iterations must be >= 1")
    sig = align_record_signals(read_signals(bag, cfg, range_of(start, end)), cfg, warn)
    sc = screen_record(sig, cfg, FaultSettings.from_params(cfg.params), warn)
    fitted = fit_record(sig, sc.index, cfg, modes, method, iters, tol)
    cfg, res, found, k = fitted.cfg, fitted.result, fitted.found, fitted.index
    r = sig.r if closed else None
    raise_if_interrupted()
    doc = json_clean(res.to_dict())
    add_stationarity(doc, fitted)
    doc["data_gaps"] = sc.gaps
    doc["screening"] = {**sc.to_dict(), "segment_s": [float(sig.t[sc.index[0]]), float(sig.t[sc.index[-1]])]}
    doc["time_range"] = sig.time_range or {"start_s": 0.0, "end_s": float(sig.t[-1]) + 1.0 / cfg.loop_rate_hz,
                                           "whole_record": True}
    if sc.used < sc.n:
        doc["message"] = (f"{doc.get('message') or ''}; identified on its longest gap-free segment without bad "
                          f"samples [{float(sig.t[sc.index[0]]):.6g}, {float(sig.t[sc.index[-1]]):.6g}] s ({sc.used} "
                          f"of {sig.n} samples)").lstrip("; ")
    _add_mode_finding(doc, found, cfg, None if r is None else r[k], sig.u[k], sig.y[k])
    figure = _order_figure(doc, found, cfg, out_path)
    doc["model_order"] = _model_order(res, cfg, None if r is None else r[k], sig.u[k], sig.y[k])
    doc = json_clean(doc)
    atomic_write_text(out_path, json.dumps(doc, indent=2, allow_nan=False) + "\n")
    if figure is not None:
        atomic_write_text(*figure)
    if out_params and doc.get("split_modes"):
        raise ValueError(f"no params file written: {doc['message']}")
    if out_params:
        write_params_file(cfg, doc, out_params, node_name, baseline, f"{bag} with {params_file}")
    return doc


def align_record_signals(sig: Signals, cfg: MonitorConfig, warn: Callable[[str], None]) -> Signals:
    """Closed loop: the record through the pipeline's stream aligner (``core/input/alignment.py``), one warning line
    when it re-aligned or refilled anything; the pairing is then what the live pipeline would have used."""
    import dataclasses

    from ..core.input.alignment import align_record
    from ..core.monitor.pipeline import _make_aligner

    if _make_aligner(cfg) is None or sig.n < 2 or cfg.controller is None or sig.r is None:
        return sig
    p = cfg.params
    blk, st = align_record(cfg.controller, cfg.loop_rate_hz, sig.t, sig.r, sig.u, sig.y,
                           max_shift=int(p.get("alignment.max_shift", 3)),
                           switch_nats=float(p.get("alignment.switch_nats", 40.0)))
    if st.realignments:
        warn(f"{st.realignments} re-alignment(s) of the signals by the controller invariant u = C_d(q)(r - y) (lost "
             f"or repeated messages): {st.reconstructed} lost sample(s) refilled, {st.surplus} surplus dropped, "
             f"{st.invalidated + st.missing - st.reconstructed} set aside")
    return dataclasses.replace(sig, t=blk.t, r=blk.r, u=blk.u, y=blk.y)


def _add_mode_finding(doc: dict, found, cfg: MonitorConfig, r, u, y) -> None:
    """JSON keys ``frf`` (summary of the nonparametric FRF: band, peaks) and ``order_selection`` (the table; empty
    when the guesses were used), plus ``mode_finding`` (message, candidates, identifiable flags)."""
    if found is not None:
        doc["frf"] = found.frf_summary()
        doc["order_selection"] = [row.to_dict() for row in found.table]
        doc["mode_finding"] = {"K": found.K, "message": found.message, "identifiable": found.identifiable,
                               "candidates": [c.to_dict() for c in found.candidates]}
        return
    from ..core.identification.frf import estimate_frf
    from ..core.identification.modefind import find_candidates

    try:
        frf = estimate_frf(u, y, cfg.loop_rate_hz, r if cfg.closed_loop else None)
    except ValueError as exc:
        doc["frf"] = {"error": str(exc)}
    else:
        doc["frf"] = frf.summary()
        doc["frf"]["peaks_hz"] = [c.natural_frequency_hz for c in find_candidates(frf, cfg.input_delay_samples)
                                  if c.natural_frequency_hz > 0]
    doc["order_selection"] = []


def _order_figure(doc: dict, found, cfg: MonitorConfig, out_path: Path) -> tuple[Path, str] | None:
    """With modes found from the data: the order scan as a stabilization diagram beside the FRF
    (:mod:`..stabilization_plot`), to be written as ``FILE.order.svg`` next to the JSON (key
    ``order_selection_figure``)."""
    if found is None:
        return None
    from ..outputs.stabilization_plot import figure_path, order_svg

    path = figure_path(out_path)
    doc["order_selection_figure"] = str(path)
    return path, order_svg(found, cfg.input_delay_samples)


def _model_order(res, cfg: MonitorConfig, r, u, y) -> dict:
    """The node's model-order check (core/identification/adequacy.py) on the identified model and the same record:
    does an
    unmodelled resonance move the identified modes? (``{"state": "off"}`` with estimator.order_check_memory_lengths
    0.)"""
    import numpy as np

    from ..core.diagnosis.faults import FaultSettings
    from ..core.identification.adequacy import check_model_order

    if cfg.estimator.order_check_memory_lengths <= 0 or not all(np.all(np.isfinite(t)) for t in res.thetas):
        return {"state": "off" if cfg.estimator.order_check_memory_lengths <= 0 else "skipped",
                "message": "" if cfg.estimator.order_check_memory_lengths <= 0 else "no finite model"}
    check = check_model_order(res.thetas, res.structures, u, y, cfg.loop_rate_hz, r=r,
                              controller=cfg.controller if r is not None else None,
                              input_delay=cfg.input_delay_samples,
                              min_change=FaultSettings.from_params(cfg.params).min_change,
                              relevance=cfg.estimator.order_check_relevance,
                              max_iterations=max(30, cfg.estimator.init_max_iterations))
    return check.to_dict()


def _num(v: Any) -> str:
    return "n/a" if not isinstance(v, int | float) else f"{v:.4g}"


def _error(exc: Exception) -> int:
    """One line on stderr: 2 for bad input (ParamError, BagError, ClosedLoopUnstableError are ValueErrors), 1 for an
    internal error (RSRIVC_DEBUG=1 re-raises it with its traceback)."""
    msg = " ".join(str(exc).split()) or type(exc).__name__
    if isinstance(exc, ValueError | OSError):
        print(f"rsrivc_identify: error: {msg}", file=sys.stderr)
        return 2
    if os.environ.get("RSRIVC_DEBUG"):
        raise exc
    print(f"rsrivc_identify: internal error: {type(exc).__name__}: {msg} (set RSRIVC_DEBUG=1 for a traceback)",
          file=sys.stderr)
    return 1


@console_entry
def main(argv: list[str] | None = None) -> int:
    """0 on success, 2 with a one-line reason on bad input, 1 on an internal error, 130/143 on SIGINT/SIGTERM
    (one line; the output file is then left as it was)."""
    with interrupts(final=argv is None):   # a console script's run: no death by signal after it
        try:
            args = _parser().parse_args(argv)
            doc = run(args.bag, args.params_file, args.out, args.method, args.max_iterations, args.tol,
                      args.node_name, modes=args.modes, out_params=args.out_params, baseline=args.baseline,
                      start=args.start, end=args.end)
        except Exception as exc:
            signum = received()
            if signum is None:
                return _error(exc)
            intr = Interrupted(signum)   # a library turned the interrupt into its own exception
            print(f"rsrivc_identify: interrupted ({intr.name}); the output file left as it was", file=sys.stderr)
            return intr.exit_code
        except KeyboardInterrupt as exc:
            print(f"rsrivc_identify: interrupted ({getattr(exc, 'name', 'SIGINT')}); the output file left as it was",
                  file=sys.stderr)
            return exit_code(exc)

    status = "converged" if doc["converged"] else f"NOT converged ({doc.get('message')})"
    print(f"rsrivc_identify: {doc['method']} {status} after {doc['iterations']} iterations; "
          f"residual variance {_num(doc.get('residual_variance'))}; wrote {args.out}")
    print(f"  {doc['stationarity']['message']}")
    for i, m in enumerate(doc["modes"], 1):
        f, z, g = m["natural_frequency_hz"], m["damping_ratio"], m["gain"]
        print(f"  mode {i}: f = {f} Hz, zeta = {z}, gain = {g}")
    if "mode_finding" in doc:
        print(f"  modes found from the data: {doc['mode_finding']['message']}")
    if doc.get("model_order", {}).get("message"):
        print(f"  model order: {doc['model_order']['message']}")
    if args.out_params:
        print(f"  wrote params file {args.out_params}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
