#!/usr/bin/env python
"""Catalogue of data problems on the bundled bag ``bags/beam_fault`` and what the fault logic makes of them.

The bag: 4096 Hz closed loop, mode 2's natural frequency -5 % at 20 s, baseline window about 11-17 s. Each case
damages the recorded stream (one lost output sample, 40 NaNs, a 2 s pause, one y = 1e300) at 12.2 s (baseline
window) or 22 s (monitoring) and prints the events, the held ("blind") time after the problem, the baseline of
mode 2 and the phase sequence. Figures, not assertions (those are in test/test_data_problems.py).

Usage: ``python scripts/study_data_problems.py [--autostart] [CASE ...]`` with CASE in none, lost1, nan40, pause2,
huge. ``--autostart``: no mode guesses (``config/beam_plant.yaml``), the damage at 2 s inside the automatic start's
first window; prints the window the modes were found on, the baseline's trust and the offline verdict.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from additive_rsrivc_ros.config import load_config
from additive_rsrivc_ros.core.monitor.pipeline import MonitorPipeline
from additive_rsrivc_ros.io.bagio import read_signals

REPO = Path(__file__).resolve().parents[1]


def damaged(sig, kind: str, t_at: float, rate: float):
    t, r, u, y = sig.t.copy(), sig.r.copy(), sig.u.copy(), sig.y.copy()
    k = int(np.searchsorted(t, t_at))
    keep = np.ones(t.size, dtype=bool)
    if kind == "lost1":
        keep[k] = False
    elif kind == "nan40":
        y[k:k + 40] = np.nan
    elif kind == "pause2":
        keep[k:k + int(2 * rate)] = False
    elif kind == "huge":
        y[k] = 1e300
    return t[keep], r[keep], u[keep], y[keep]


def _through_pipeline(cfg, t, r, u, y) -> tuple[MonitorPipeline, list]:
    """The samples through a fresh pipeline in 0.1 s batches; the pipeline and its reports."""
    pipe = MonitorPipeline(cfg)
    n = int(cfg.loop_rate_hz / 10)
    reps = []
    for a in range(0, t.size, n):
        reps += pipe.push(t[a:a + n], r[a:a + n], u[a:a + n], y[a:a + n])
    return pipe, reps


def run(cfg, sig, kind: str, t_at: float) -> None:
    t, r, u, y = damaged(sig, kind, t_at, cfg.loop_rate_hz)
    _, reps = _through_pipeline(cfg, t, r, u, y)
    ev = [(e.mode, e.quantity, e.direction, round(e.onset_time_s, 2), round(e.alarm_time_s, 2))
          for x in reps for e in x.events_opened]
    held = [x.time_s for x in reps if x.time_s >= t_at and x.health["hold"]] if kind != "none" else []
    blind = f"{max(held) - t_at + 0.1:.1f} s" if held else "0 s"
    phases = []
    for x in reps:
        if not phases or phases[-1][0] != x.phase:
            phases.append((x.phase, round(x.time_s, 1)))
    last = reps[-1]
    print(f"{kind:6s} @ {t_at:4.1f} s: events {ev}; held after the problem {blind}; baseline f2 "
          f"{last.baseline[1, 0]:.3f} Hz (trusted {last.health['baseline_trusted']}); phases {phases}")


def run_autostart(cfg, sig, kind: str, t_at: float) -> None:
    """No mode guesses (``config/beam_plant.yaml``): the damage lands in the automatic start's first window. Prints
    the window the modes were found on, the baseline's trust and note, and the offline verdict."""
    from additive_rsrivc_ros.outputs.verdict import assess

    t, r, u, y = damaged(sig, kind, t_at, cfg.loop_rate_hz)
    pipe, reps = _through_pipeline(cfg, t, r, u, y)
    reps += pipe.flush()
    found = pipe.search.found if pipe.search is not None else None
    win = "none" if found is None else f"{found.window_s[0]:.1f}-{found.window_s[1]:.1f} s"
    last = reps[-1].health
    verdict = assess(reps, float(t[-1]) + 1.0 / cfg.loop_rate_hz)   # the events from the reports, as the tools do
    print(f"{kind:6s} @ {t_at:4.1f} s: modes found on {win}; baseline trusted {last['baseline_trusted']} "
          f"({last['baseline_note'] or 'complete window'}); {verdict.line}")


def main() -> None:
    args = sys.argv[1:]
    autostart = "--autostart" in args
    kinds = [a for a in args if a != "--autostart"] or ["none", "lost1", "nan40", "pause2", "huge"]
    cfg = load_config(REPO / "config" / ("beam_plant.yaml" if autostart else "beam_fault.yaml"))
    sig = read_signals(REPO / "bags" / "beam_fault", cfg)
    for kind in kinds:
        for t_at in ((0.0,) if kind == "none" else (2.0,) if autostart else (12.2, 22.0)):
            (run_autostart if autostart else run)(cfg, sig, kind, t_at)
            sys.stdout.flush()


if __name__ == "__main__":
    main()
