"""``rsrivc_identify BAG --params-file YAML --out FILE.json [--method NAME]`` (../shared/CONTRACT.md).

Offline (non-recursive) identification of the whole bag with the node's params file: the modes' guesses
(``modes.*``), the controller, the input delay and ``closed_loop`` come from the YAML. Writes one JSON object:
``method``, ``converged``, ``iterations``, ``modes`` (per mode ``theta``, ``theta_std`` in 000 eq. 7 order,
``natural_frequency_hz``, ``damping_ratio``, ``gain`` and their ``_std``), ``residual_variance`` (plus
``cost``, ``cond``, ``projections``, ``message``, ``n_samples``). Exit status 0 on success (also when the
estimator did not converge: see ``converged``/``message``), 2 with a one-line reason on bad input.

``--modes K|auto`` (or a params file without guesses): the modes are first found from the data
(``core/modefind.py``: FRF peaks refined by the offline additive (CL)SRIVC, K chosen by held-out output error for
``auto``); the JSON gains ``frf`` (FRF summary: method, resolution, valid band, peaks), ``order_selection`` (K, fit
error, validation error, accepted) and ``mode_finding``. ``--out-params FILE.yaml`` writes a complete, commented
params file for the node (input params + identified ``modes.*``; ``--baseline`` adds ``faults.baseline.*``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from ..config import ParamError, load_config
from ..core.faults import FaultSettings
from ..core.filters import ClosedLoopUnstableError
from ..core.offline import METHODS, identify

CLI_METHODS = tuple(m for m in METHODS if not m.endswith("-monic"))


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="rsrivc_identify", description=__doc__.split("\n\n")[0])
    ap.add_argument("bag", help="rosbag2 directory (mcap or sqlite3)")
    ap.add_argument("--params-file", required=True, help="params YAML of the monitor node")
    ap.add_argument("--out", required=True, help="output JSON file")
    ap.add_argument("--method", default="auto", choices=CLI_METHODS,
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
    if t.size < 2:
        return slice(0, t.size), 0
    breaks = np.flatnonzero(np.diff(t) > (1.0 + tolerance) / rate_hz) + 1
    edges = np.concatenate(([0], breaks, [t.size]))
    k = int(np.argmax(np.diff(edges)))
    return slice(int(edges[k]), int(edges[k + 1])), int(breaks.size)


def write_params_file(cfg, doc: dict, path: str, node_name: str | None, baseline: bool, source: str) -> None:
    """The input params with the identified ``modes.*`` (and ``faults.baseline.*`` when ``baseline``) as a complete,
    commented params YAML for the node, written atomically."""
    from ..config import DEFAULT_NODE_NAME, render_params_yaml

    p = dict(cfg.params)
    modes = doc["modes"]
    for key in ("natural_frequency_hz", "damping_ratio", "gain"):
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
    tmp = out_path.with_name(f".{out_path.name}.tmp")
    tmp.write_text(text)
    tmp.replace(out_path)


def run(bag: str, params_file: str, out: str, method: str = "auto", max_iterations: int | None = None,
        tol: float = 1e-7, node_name: str | None = None, modes: int | None = None, out_params: str | None = None,
        baseline: bool = False) -> dict:
    """Identify the bag and write the JSON; returns the JSON object. Raises ``ValueError`` on bad input."""
    from ..bagio import read_signals

    cfg = load_config(params_file) if node_name is None else load_config(params_file, node_name)
    sig = read_signals(bag, cfg)
    bad = [name for name, s in (("reference", sig.r), ("input", sig.u), ("output", sig.y))
           if s is not None and not np.all(np.isfinite(s))]
    if bad:
        raise ValueError(f"bag {bag}: non-finite samples in {', '.join(bad)}")
    closed = cfg.closed_loop
    if baseline and not out_params:
        raise ValueError("--baseline needs --out-params")
    if method in ("additive-clsrivc", "clsrivc", "clsrivc-uns") and not closed:
        raise ValueError(f"method {method} needs closed-loop data (closed_loop: true and a controller)")
    iters = max_iterations if max_iterations is not None else max(50, cfg.estimator.init_max_iterations)
    if iters < 1:
        raise ValueError("--max-iterations must be >= 1")
    seg, n_gaps = longest_gap_free(sig.t, cfg.loop_rate_hz, FaultSettings.from_params(cfg.params).health_gap_tolerance)
    r_seg = sig.r[seg] if closed else None
    found = None
    if cfg.auto_modes or modes is not None:
        from ..core.modefind import autostart_config

        cfg, found = autostart_config(cfg, r_seg, sig.u[seg], sig.y[seg], modes)
    res = identify(sig.u[seg], sig.y[seg], cfg.loop_rate_hz, cfg.structures, [m.theta0() for m in cfg.modes],
                   r=r_seg, controller=cfg.controller if closed else None,
                   input_delay=cfg.input_delay_samples, method=method, max_iterations=iters, tol=tol,
                   projection=cfg.estimator.stability_projection)
    doc = res.to_dict()
    doc["data_gaps"] = n_gaps
    _add_mode_finding(doc, found, cfg, r_seg, sig.u[seg], sig.y[seg])
    if n_gaps:
        t_a, t_b = float(sig.t[seg.start]), float(sig.t[seg.stop - 1])
        doc["message"] += (f"; the bag has {n_gaps} data gap(s): identified on its longest gap-free segment "
                           f"[{t_a:.6g}, {t_b:.6g}] s ({seg.stop - seg.start} of {sig.n} samples)")
        print(f"rsrivc_identify: warning: {n_gaps} data gap(s) in the bag; the filters need evenly spaced samples, so "
              f"only the longest gap-free segment [{t_a:.6g}, {t_b:.6g}] s is used", file=sys.stderr)
    out_path = Path(out)
    if out_path.parent and not out_path.parent.exists():
        raise ValueError(f"output directory {out_path.parent} does not exist")
    tmp = out_path.with_name(f".{out_path.name}.tmp")
    tmp.write_text(json.dumps(doc, indent=2) + "\n")
    tmp.replace(out_path)
    if out_params:
        write_params_file(cfg, doc, out_params, node_name, baseline, f"{bag} with {params_file}")
    return doc


def _add_mode_finding(doc: dict, found, cfg, r, u, y) -> None:
    """JSON keys ``frf`` (summary of the nonparametric FRF: band, peaks) and ``order_selection`` (the table; empty
    when the guesses were used), plus ``mode_finding`` (message, candidates, identifiable flags)."""
    if found is not None:
        doc["frf"] = found.frf_summary()
        doc["order_selection"] = [row.to_dict() for row in found.table]
        doc["mode_finding"] = {"K": found.K, "message": found.message, "identifiable": found.identifiable,
                               "candidates": [c.to_dict() for c in found.candidates]}
        return
    from ..core.frf import estimate_frf
    from ..core.modefind import find_candidates

    try:
        frf = estimate_frf(u, y, cfg.loop_rate_hz, r if cfg.closed_loop else None)
    except ValueError as exc:
        doc["frf"] = {"error": str(exc)}
    else:
        doc["frf"] = frf.summary()
        doc["frf"]["peaks_hz"] = [c.natural_frequency_hz for c in find_candidates(frf, cfg.input_delay_samples)
                                  if c.natural_frequency_hz > 0]
    doc["order_selection"] = []


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    try:
        doc = run(args.bag, args.params_file, args.out, args.method, args.max_iterations, args.tol, args.node_name,
                  args.modes, args.out_params, args.baseline)
    except (ParamError, ClosedLoopUnstableError, ValueError, OSError) as exc:
        msg = " ".join(str(exc).split())
        print(f"rsrivc_identify: error: {msg}", file=sys.stderr)
        return 2
    status = "converged" if doc["converged"] else f"NOT converged ({doc['message']})"
    print(f"rsrivc_identify: {doc['method']} {status} after {doc['iterations']} iterations; "
          f"residual variance {doc['residual_variance']:.4g}; wrote {args.out}")
    for i, m in enumerate(doc["modes"], 1):
        f, z, g = m["natural_frequency_hz"], m["damping_ratio"], m["gain"]
        print(f"  mode {i}: f = {f} Hz, zeta = {z}, gain = {g}")
    if "mode_finding" in doc:
        print(f"  modes found from the data: {doc['mode_finding']['message']}")
    if args.out_params:
        print(f"  wrote params file {args.out_params}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
