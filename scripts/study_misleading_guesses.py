#!/usr/bin/env python
"""Misleading guesses on a HEALTHY plant never raise a structural alarm.

The plant: the beam (``beam_healthy`` scenario: 4096 Hz closed loop, 4-sample delay, square-wave setpoint; truth
3.2487 Hz / 0.2348 / 11.81 and 32.972 Hz / 0.01709 / 0.159, two more unmodelled modes at 172 and 183 Hz), constant
parameters, so every structural event is a false alarm. Each case starts the same pipeline (the node's, via
``MonitorPipeline``) from different guesses:

* ``truth``: the true values (reference);
* ``50% over`` / ``50% under``: every frequency x1.5 / x0.5, damping 0.1, gains x3 / x(1/3);
* ``log-spaced``: K frequencies log-spaced inside 1 Hz-1 kHz, damping 0.1, gain 1 (someone who knows nothing);
* ``K+1``: three log-spaced guesses (one mode too many); ``K-1``: one guess at the lower mode (one too few);
* ``truth+1``: the true two modes plus a third guess at 100 Hz, where the plant has no mode.

Printed per case: structural events (must be 0), the end estimate of each mode against the nearest true mode,
whether the end health is flagged, the model-order check's finding (core/identification/adequacy.py: ``too_low``
flags health,
``adequate`` does not) and the verdict line "trust": an estimate more than 1 % (frequency) off the truth must come with
a flagged health, or it is *confidently wrong*.

Usage: ``python scripts/study_misleading_guesses.py [--duration S] [--seed N] [CASE ...]``
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from additive_rsrivc_ros.config import MonitorConfig, load_params_file
from additive_rsrivc_ros.core.monitor.pipeline import MonitorPipeline
from additive_rsrivc_ros.sim.scenarios import build, config_dir

TRUE_F = np.array([3.2487, 32.972, 171.7, 183.2])
TRUE_Z = np.array([0.2348, 0.01709, 0.0056, 0.0020])
TRUE_G = np.array([11.81, 0.159, 3.19e-4, 1.27e-4])


def _log_spaced(k: int, lo: float = 1.0, hi: float = 1000.0) -> list[float]:
    return list(np.geomspace(lo, hi, k + 2)[1:-1])


CASES: dict[str, dict[str, list[float]]] = {
    "truth": {"f": [3.2487, 32.972], "z": [0.2348, 0.01709], "g": [11.81, 0.159]},
    "50% over": {"f": [4.873, 49.46], "z": [0.1, 0.1], "g": [35.43, 0.477]},
    "50% under": {"f": [1.624, 16.49], "z": [0.1, 0.1], "g": [3.937, 0.053]},
    "log-spaced": {"f": _log_spaced(2), "z": [0.1, 0.1], "g": [1.0, 1.0]},
    "K+1": {"f": _log_spaced(3), "z": [0.1, 0.1, 0.1], "g": [1.0, 1.0, 1.0]},
    "K-1": {"f": [3.2487], "z": [0.2348], "g": [11.81]},
    "truth+1": {"f": [3.2487, 32.972, 100.0], "z": [0.2348, 0.01709, 0.05], "g": [11.81, 0.159, 1e-3]},
}


def config_for(guess: dict[str, list[float]]) -> MonitorConfig:
    p = dict(load_params_file(config_dir() / "beam_healthy.yaml"))
    k = len(guess["f"])
    memories = [2.44, 0.244, 0.244][:k]
    p.update({"modes.natural_frequency_hz": guess["f"], "modes.damping_ratio": guess["z"],
              "modes.gain": guess["g"], "modes.integrators": [0] * k, "modes.memory_s": memories})
    return MonitorConfig.from_params(p)


def run_case(name: str, data, chunk: int = 4096) -> dict:
    cfg = config_for(CASES[name])
    pipe = MonitorPipeline(cfg)
    events, reports = [], []
    for a in range(0, data.t.size, chunk):
        b = min(a + chunk, data.t.size)
        for rep in pipe.push(data.t[a:b], data.r[a:b], data.u[a:b], data.y[a:b]):
            reports.append(rep)
            events += list(rep.events_opened)
    for rep in pipe.flush():
        reports.append(rep)
        events += list(rep.events_opened)
    last = reports[-1]
    flagged_since = None
    for rep in reports:                     # the last unbroken stretch of flagged health
        flagged = int(rep.health.get("level", 0)) > 0
        flagged_since = (flagged_since if flagged_since is not None else rep.time_s) if flagged else None
    modal = np.asarray(last.modal)
    rows = []
    for i in range(cfg.K):
        f = float(modal[i, 0])
        j = int(np.argmin(np.abs(np.log(TRUE_F / f)))) if np.isfinite(f) and f > 0 else 0
        rows.append((i + 1, f, float(modal[i, 1]), float(modal[i, 2]), j + 1,
                     (f / TRUE_F[j] - 1) * 100 if np.isfinite(f) else np.nan))
    health = last.health
    order = dict(health.get("model_order", {}))
    result = pipe.order_check.result           # the check's wall time is not in health (outputs stay reproducible)
    order["seconds"] = result.seconds if result is not None else 0.0
    return {"events": events, "rows": rows, "level": int(health.get("level", 0)), "order": order,
            "reasons": list(health.get("reasons", []))[:2], "flagged_since": flagged_since,
            "estimating": bool(last.estimating)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("cases", nargs="*", default=list(CASES))
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    data = build("beam_healthy", duration_s=args.duration, seed=args.seed)
    confident_wrong = false_alarms = 0
    print(f"beam_healthy, {args.duration:g} s, seed {args.seed}: 0 structural events expected in every case\n")
    for name in args.cases:
        res = run_case(name, data)
        n_ev = len(res["events"])
        false_alarms += n_ev
        off = [abs(r[5]) for r in res["rows"] if np.isfinite(r[5])]
        wrong = (not off or max(off) > 1.0 or not res["estimating"])
        trusted = res["level"] == 0 and res["estimating"]
        verdict = "OK" if not (wrong and trusted) else "CONFIDENTLY WRONG"
        confident_wrong += verdict != "OK"
        since = "" if res["flagged_since"] is None else f" (flagged since {res['flagged_since']:.1f} s)"
        print(f"{name:11s} events {n_ev}  end health level {res['level']}{since}  -> {verdict}")
        for i, f, z, g, j, pct in res["rows"]:
            print(f"    mode {i}: {f:9.4g} Hz  zeta {z:8.3g}  gain {g:9.3g}   nearest true mode {j} "
                  f"({TRUE_F[j - 1]:g} Hz): {pct:+.2f} %")
        order = res["order"]
        flag = "FLAGS health" if order.get("state") == "too_low" else "no flag"
        print(f"    model-order check ({order.get('seconds') or 0:.2f} s): {order.get('state', '?')}, {flag}: "
              f"{order.get('message', '')[:150]}")
        for e in res["events"]:
            print(f"    EVENT mode {e.mode} {e.quantity} at {e.alarm_time_s:.2f} s")
        for reason in res["reasons"]:
            print(f"    health: {reason[:150]}")
    print(f"\nstructural events on healthy data: {false_alarms} (target 0); confidently wrong cases: "
          f"{confident_wrong} (target 0)")
    return 0 if false_alarms == 0 and confident_wrong == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
