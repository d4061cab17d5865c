#!/usr/bin/env python
"""Other CPUs' rounding, emulated: the misleading-guess cases of ``study_misleading_guesses.py`` (healthy beam) run
from guesses scaled by ``1 + j 1e-12`` (j = 0..N-1), each a different rounding path through the same data, as
another machine's arithmetic would take (a test that passed here failed on another CPU for that reason).

Per case and path, over every report (not only the end): the seconds of reports with health OK while the estimate is
wrong (a modelled mode more than 5 % off the nearest true mode, a damping ratio of 1 or more, or a non-finite
value), the seconds of wrong estimates at all, structural events (false alarms: the plant is healthy) and the end
error. Must be 0.0 s and 0 events on every path.

Usage: ``python scripts/study_rounding_paths.py [--paths 5] [--duration 60] [--seed 0] [CASE ...]``
"""

from __future__ import annotations

import argparse
import sys

import numpy as np
from study_misleading_guesses import CASES, TRUE_F, TRUE_Z, config_for

from additive_rsrivc_ros.core.monitor.pipeline import MonitorPipeline
from additive_rsrivc_ros.sim.scenarios import build


def _scaled(guess: dict[str, list[float]], scale: float) -> dict[str, list[float]]:
    return {**guess, "f": [f * scale for f in guess["f"]]}


def run_path(name: str, scale: float, data, chunk: int = 4096) -> dict[str, float]:
    """One run of case ``name`` from its guesses times ``scale``: wrong / healthy-while-wrong seconds, events, end
    error (largest of the modelled modes against their nearest true mode)."""
    cfg = config_for(_scaled(CASES[name], scale))
    pipe = MonitorPipeline(cfg)
    period = 1.0 / cfg.publish_rate_hz
    wrong_s = wrong_ok_s = 0.0
    events, last = 0, None
    for a in range(0, data.t.size, chunk):
        b = min(a + chunk, data.t.size)
        for rep in [*pipe.push(data.t[a:b], data.r[a:b], data.u[a:b], data.y[a:b]),
                    *(pipe.flush() if b == data.t.size else [])]:
            events += len(rep.events_opened)
            last = rep
            if not rep.estimating:
                continue
            f, zeta = np.asarray(rep.modal)[:, 0], np.asarray(rep.modal)[:, 1]
            with np.errstate(divide="ignore", invalid="ignore"):
                off = np.min(np.abs(f[:, None] / TRUE_F[None, :] - 1.0), axis=1)
            wrong = bool(not np.all(np.isfinite(f)) or np.any(off > 0.05) or np.any(zeta >= 1.0))
            wrong_s += period if wrong else 0.0
            wrong_ok_s += period if wrong and int(rep.health.get("level", 0)) == 0 else 0.0
    f_end = np.asarray(last.modal)[:, 0] if last is not None else np.array([np.nan])
    with np.errstate(divide="ignore", invalid="ignore"):
        end = float(np.max(np.min(np.abs(f_end[:, None] / TRUE_F[None, :] - 1.0), axis=1)))
    return {"wrong_s": wrong_s, "wrong_ok_s": wrong_ok_s, "events": events, "end_error": end,
            "end_level": int(last.health.get("level", 0)) if last is not None else -1}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("cases", nargs="*", default=list(CASES))
    ap.add_argument("--paths", type=int, default=5, help="rounding paths per case (guesses x (1 + j 1e-12))")
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    data = build("beam_healthy", duration_s=args.duration, seed=args.seed)
    print(f"beam_healthy, {args.duration:g} s, seed {args.seed}; true modes {TRUE_F} Hz, zeta {TRUE_Z}; "
          f"{args.paths} rounding paths per case")
    print(f"{'case':<11} {'j':>2} {'wrong s':>8} {'wrong+OK s':>10} {'events':>6} {'end level':>9} {'end err %':>9}")
    worst_ok, total_events = 0.0, 0
    for name in args.cases:
        for j in range(args.paths):
            x = run_path(name, 1.0 + j * 1e-12, data)
            worst_ok = max(worst_ok, x["wrong_ok_s"])
            total_events += x["events"]
            print(f"{name:<11} {j:>2} {x['wrong_s']:8.1f} {x['wrong_ok_s']:10.1f} {x['events']:>6} "
                  f"{x['end_level']:>9} {100 * x['end_error']:9.3f}")
    print(f"\nmost seconds of health OK while wrong in one path: {worst_ok:.1f} s (target 0); structural "
          f"events on healthy data: {total_events} (target 0)")
    return 0 if worst_ok == 0.0 and total_events == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
