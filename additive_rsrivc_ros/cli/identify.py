"""``rsrivc_identify BAG --params-file YAML --out FILE.json [--method NAME]`` (../shared/CONTRACT.md).

Offline (non-recursive) identification of the whole bag with the node's params file: the modes' guesses
(``modes.*``), the controller, the input delay and ``closed_loop`` come from the YAML. Writes one JSON object:
``method``, ``converged``, ``iterations``, ``modes`` (per mode ``theta``, ``theta_std`` in 000 eq. 7 order,
``natural_frequency_hz``, ``damping_ratio``, ``gain`` and their ``_std``), ``residual_variance`` (plus
``cost``, ``cond``, ``projections``, ``message``, ``n_samples``). Exit status 0 on success (also when the
estimator did not converge: see ``converged``/``message``), 2 with a one-line reason on bad input.
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
    return ap


def longest_gap_free(t: np.ndarray, rate_hz: float, tolerance: float) -> tuple[slice, int]:
    """Longest run of samples spaced by at most ``(1 + tolerance)/rate_hz`` and the number of gaps in ``t`` (the
    gap rule of the pipeline, ``faults.health.gap_tolerance``)."""
    if t.size < 2:
        return slice(0, t.size), 0
    breaks = np.flatnonzero(np.diff(t) > (1.0 + tolerance) / rate_hz) + 1
    edges = np.concatenate(([0], breaks, [t.size]))
    k = int(np.argmax(np.diff(edges)))
    return slice(int(edges[k]), int(edges[k + 1])), int(breaks.size)


def run(bag: str, params_file: str, out: str, method: str = "auto", max_iterations: int | None = None,
        tol: float = 1e-7, node_name: str | None = None) -> dict:
    """Identify the bag and write the JSON; returns the JSON object. Raises ``ValueError`` on bad input."""
    from ..bagio import read_signals

    cfg = load_config(params_file) if node_name is None else load_config(params_file, node_name)
    sig = read_signals(bag, cfg)
    bad = [name for name, s in (("reference", sig.r), ("input", sig.u), ("output", sig.y))
           if s is not None and not np.all(np.isfinite(s))]
    if bad:
        raise ValueError(f"bag {bag}: non-finite samples in {', '.join(bad)}")
    closed = cfg.closed_loop
    if method in ("additive-clsrivc", "clsrivc", "clsrivc-uns") and not closed:
        raise ValueError(f"method {method} needs closed-loop data (closed_loop: true and a controller)")
    iters = max_iterations if max_iterations is not None else max(50, cfg.estimator.init_max_iterations)
    if iters < 1:
        raise ValueError("--max-iterations must be >= 1")
    seg, n_gaps = longest_gap_free(sig.t, cfg.loop_rate_hz, FaultSettings.from_params(cfg.params).health_gap_tolerance)
    r_seg = sig.r[seg] if closed else None
    res = identify(sig.u[seg], sig.y[seg], cfg.loop_rate_hz, cfg.structures, [m.theta0() for m in cfg.modes],
                   r=r_seg, controller=cfg.controller if closed else None,
                   input_delay=cfg.input_delay_samples, method=method, max_iterations=iters, tol=tol,
                   projection=cfg.estimator.stability_projection)
    doc = res.to_dict()
    doc["data_gaps"] = n_gaps
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
    return doc


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    try:
        doc = run(args.bag, args.params_file, args.out, args.method, args.max_iterations, args.tol, args.node_name)
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
    return 0


if __name__ == "__main__":
    sys.exit(main())
