"""Guesses that lead to a wrong optimum: 5 and 5.5 Hz for the 5 Hz + 40 Hz closed loop of test_pipeline_autostart
(60 s, seed 11), through ``MonitorPipeline`` as the node and ``rsrivc_diagnose`` run it.

``python scripts/study_wrong_optimum.py [--seed 11]`` prints the notices, the seconds of reports published with
health OK while the estimate is wrong (a mode more than 5 % off its true frequency, the modes matched in order, or
a damping ratio of 1 or more), when a check first flagged the model (its notice), and the end error. ``--tree DIR``:
the package of another checkout (``git worktree add DIR REV``), to see an earlier revision on the same data.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np


def run_case(seed: int, scale: float = 1.0, verbose: bool = True) -> dict:
    """One 60 s run from the guesses 5 and 5.5 Hz (times ``scale``): the seconds of wrong estimates, of wrong
    estimates with health OK, the first flag, events, re-initializations and the end error."""
    from test_pipeline_autostart import MODES, _cfg, _run, _sim

    t, r, u, y = _sim(seed, 60.0)
    cfg = _cfg(**{"modes.natural_frequency_hz": [5.0 * scale, 5.5 * scale], "modes.damping_ratio": [0.1, 0.1],
                  "modes.gain": [1.0, 1.0], "modes.memory_s": [5.0, 5.0]})
    pipe, reports = _run(cfg, t, r, u, y)
    truth = np.array([m.natural_frequency_hz for m in MODES])
    period = 1.0 / cfg.publish_rate_hz
    wrong_s, wrong_ok, flagged_at = 0.0, 0.0, None
    for rep in reports:
        if verbose:
            for n in rep.notices:
                print(f"{rep.time_s:6.1f} s  {n[:220]}")
        if not rep.estimating:
            continue
        f, zeta = rep.modal[:, 0], rep.modal[:, 1]
        off = np.abs(np.sort(f) / np.sort(truth) - 1.0)   # the modes matched in order: a missing mode is wrong too
        wrong = bool(np.any(off > 0.05) or np.any(zeta >= 1.0) or not np.all(np.isfinite(f)))
        wrong_s += period if wrong else 0.0
        if wrong and int(rep.health["level"]) == 0:
            wrong_ok += period
        flags = [n for n in rep.notices if n.startswith(("model check of", "model-order check on"))] + \
            ([1] if rep.health.get("model_order", {}).get("state") in ("misfit", "too_low") else [])
        if flagged_at is None and flags:
            flagged_at = rep.time_s
    err = np.abs(np.sort(reports[-1].modal[:, 0]) / np.sort(truth) - 1.0)
    return {"wrong_s": wrong_s, "wrong_ok_s": wrong_ok, "flagged_at": flagged_at,
            "events": sum(len(rep.events_opened) for rep in reports),
            "reinitializations": pipe.counters.reinitializations, "end_error": float(np.max(err))}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--tree", help="import additive_rsrivc_ros from this checkout")
    ap.add_argument("--perturb", type=int, default=0, metavar="N",
                    help="N more runs with the guesses scaled by 1 + j 1e-12 (j = 1..N): another rounding path each, "
                         "as another CPU would take; one line per run")
    args = ap.parse_args(argv)
    if args.tree:
        sys.path.insert(0, str(Path(args.tree).resolve()))
    sys.path.append(str(Path(__file__).resolve().parents[1] / "test"))

    import additive_rsrivc_ros

    print(f"package: {Path(additive_rsrivc_ros.__file__).parent}")
    res = run_case(args.seed, verbose=not args.perturb)
    rows = [(0, res)] + [(j, run_case(args.seed, 1.0 + j * 1e-12, verbose=False)) for j in range(1, args.perturb + 1)]
    if not args.perturb:
        flagged = "never" if res["flagged_at"] is None else f"{res['flagged_at']:.1f} s"
        print(f"\nreports with health OK while the estimate was wrong: {res['wrong_ok_s']:.1f} s; model first "
              f"flagged at {flagged}; structural events {res['events']}; re-initializations "
              f"{res['reinitializations']}; end frequency error {100 * res['end_error']:.3f} %")
        return 0
    print(f"{'j':>3} {'wrong s':>8} {'wrong+OK s':>10} {'flagged':>8} {'events':>6} {'reinit':>6} {'end err %':>9}")
    for j, x in rows:
        flag = "never" if x["flagged_at"] is None else f"{x['flagged_at']:.1f}"
        print(f"{j:>3} {x['wrong_s']:8.1f} {x['wrong_ok_s']:10.1f} {flag:>8} {x['events']:>6} "
              f"{x['reinitializations']:>6} {100 * x['end_error']:9.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
