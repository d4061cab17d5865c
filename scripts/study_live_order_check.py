#!/usr/bin/env python3
"""The live model-order check on healthy plants: does it cry wolf? (the misfit-run rule)

The pipeline checks the model once per run on a window of ``estimator.order_check_memory_lengths`` memory lengths
after the initialization (``adequacy.ModelOrderCheck``), against the current estimate. A healthy plant whose modes
are all modelled, or whose unmodelled modes do not move the modelled ones (the beam's 172/183 Hz modes with K = 2),
must come out ``adequate``, also with long misfit runs around an unmodelled resonance (the run rule of
``adequacy.MISFIT_RUN_BINS`` only flags a run that no real extra mode explains). Each healthy scenario (the fault
sizes set to 0) runs through ``MonitorPipeline`` with its own params file, fed in one-second batches as the node
would; prints the check's window, state, longest misfit run and its band, the reports flagged on health by the
check, the structural events (0 expected everywhere), column ``base`` the baseline at the end (``T`` trusted, ``U``
untrusted: 0 expected on these healthy plants), column ``delay`` the output error of the better of the two
neighbouring input delays over the configured (true) one's (step 0 flags below ``adequacy.DELAY_ERROR_RATIO``), and
column ``check s`` the check's own seconds.

    python scripts/study_live_order_check.py [--seeds 3] [--random 20] [--path J]

``--random N``: also N random closed-loop plants of ``validate_autostart.py`` (1-4 modes, 1-8 kHz loops, delay 0-2
samples, PI loop, square wave plus dither, 40 s), configured correctly (their true modes as guesses, memories
10 periods of the lowest mode, at most 5 s): the same columns. ``--path J``: every record on another rounding path
(the outputs times ``1 + J 1e-12``, as another CPU's arithmetic would take): the table should not depend on it.
"""

from __future__ import annotations

import argparse
import os
import sys

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from additive_rsrivc_ros.core.monitor.pipeline import MonitorPipeline  # noqa: E402
from additive_rsrivc_ros.sim.scenarios import build  # noqa: E402

#: (scenario, overrides making it healthy, seconds): every window fits (memory lengths x longest memory + init)
CASES = (("beam_healthy", {}, 60.0), ("beam_fault", {"fault_size": 0.0}, 60.0),
         ("open_loop_multisine", {}, 300.0), ("rigid_body", {"fault_size": 0.0}, 300.0),
         ("paper_example", {"drift1_start_s": 1e9, "drift1_end_s": 2e9, "drift2_start_s": 1e9, "drift2_end_s": 2e9},
          400.0))


def run_case(name: str, overrides: dict, seconds: float, seed: int, path: int = 0) -> dict:
    sc = build(name, duration_s=seconds, seed=seed, **overrides)
    return _through_pipeline(sc.config, sc.t, sc.r, sc.u, sc.y, path)


def run_random(seed: int, path: int = 0) -> tuple[str, dict]:
    """A random plant of ``validate_autostart.py`` through the pipeline with its true modes as guesses."""
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    import validate_autostart as va

    from additive_rsrivc_ros.config import MonitorConfig, validate_params

    rng = np.random.default_rng(seed)
    modes, rate, delay = va.random_plant(rng)
    ctrl = va.design_controller(modes, rate, delay)
    f0 = modes[0].natural_frequency_hz
    t = np.arange(int(40.0 * rate)) / rate
    r = va.square_wave(t, min(2.0, f0 / 5.0), 1.0) + va.white_noise(t.size, 0.05, rng)
    clean = va.simulate_modes(modes, rate, r=r, controller=ctrl, input_delay=delay)
    sim = va.simulate_modes(modes, rate, r=r, controller=ctrl, input_delay=delay,
                            noise=va.white_noise(t.size, 0.01 * float(np.std(clean.y)), rng), rng=rng)
    cfg = MonitorConfig.from_params(validate_params({
        "loop_rate_hz": rate, "closed_loop": True, "controller.numerator": list(ctrl.numerator),
        "controller.denominator": list(ctrl.denominator), "input_delay_samples": delay, "init_duration_s": 10.0,
        "alignment.mode": "off", "modes.natural_frequency_hz": [m.natural_frequency_hz for m in modes],
        "modes.damping_ratio": [m.damping_ratio for m in modes], "modes.gain": [m.gain for m in modes],
        "modes.integrators": [0] * len(modes), "modes.memory_s": [min(max(1.0, 10.0 / f0), 5.0)] * len(modes)}))
    name = f"random {rate:.0f} Hz d={delay} K={len(modes)}"
    return name, _through_pipeline(cfg, t, r, sim.u, sim.y, path)


def _through_pipeline(cfg, t, r, u, y, path: int = 0) -> dict:
    """The record through the pipeline in one-second batches; ``path``: the outputs times ``1 + path 1e-12`` (another
    CPU's rounding, emulated)."""
    y = y * (1.0 + path * 1e-12) if path else y
    pipe = MonitorPipeline(cfg)
    step = max(1, int(cfg.loop_rate_hz))
    reports = []
    for j in range(0, t.size, step):
        sl = slice(j, j + step)
        reports += pipe.push(t[sl], None if r is None else r[sl], u[sl], y[sl])
    res = pipe.order_check.result
    flagged = sum(1 for rp in reports if rp.health.get("model_order", {}).get("state") in ("misfit", "too_low"))
    ratios = {} if res is None or res.delay is None else res.delay.ratios
    return {"window": None if res is None else res.window_s, "state": "none" if res is None else res.state,
            "delay_ratio": min(ratios.values()) if ratios else np.nan,
            "run": None if res is None else res.misfit_run, "flagged_reports": flagged,
            "events": sum(len(rp.events_opened) for rp in reports), "baseline": _baseline_state(pipe),
            "seconds": np.nan if res is None else res.seconds}


def _baseline_state(pipe) -> str:
    """``-`` no baseline yet, ``T`` trusted, ``U`` untrusted (cut short, or its thirds differ:
    ``core/diagnosis/baseline_phases.py``)."""
    base = None if pipe.faults is None else pipe.faults.baseline
    return "-" if base is None else ("T" if base.trusted else "U")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--random", type=int, default=0, metavar="N", help="also N random closed-loop plants")
    ap.add_argument("--path", type=int, default=0, metavar="J",
                    help="a rounding path: the outputs times 1 + J 1e-12, as another CPU's arithmetic would take")
    args = ap.parse_args(argv)
    print(f"{'scenario':<28} {'seed':>4} {'window [s]':>14} {'state':>10} {'run':>4} {'run band [Hz]':>16} "
          f"{'flagged':>7} {'events':>6} {'delay':>6} {'base':>4} {'check s':>7}")
    total = {"checks": 0, "flagged": 0, "events": 0, "longest": 0, "delay": np.inf, "untrusted": 0, "baselines": 0}
    jobs = [(seed, lambda n=name, o=over, sec=seconds, sd=seed: (n, run_case(n, o, sec, sd, args.path)))
            for name, over, seconds in CASES for seed in range(args.seeds)]
    jobs += [(500 + i, lambda sd=500 + i: run_random(sd, args.path)) for i in range(args.random)]
    for seed, job in jobs:
        name, row = job()
        run = row["run"] or (0, np.nan, np.nan)
        win = row["window"] or (np.nan, np.nan)
        print(f"{name:<28} {seed:>4} {win[0]:6.1f}-{win[1]:6.1f} {row['state']:>10} {run[0]:>4} "
              f"{run[1]:7.2f}-{run[2]:7.2f} {row['flagged_reports']:>7} {row['events']:>6} "
              f"{row['delay_ratio']:6.2f} {row['baseline']:>4} {row['seconds']:7.2f}", flush=True)
        total["checks"] += row["state"] != "none"
        total["flagged"] += row["state"] in ("misfit", "too_low")
        total["events"] += row["events"]
        total["longest"] = max(total["longest"], int(run[0]))
        total["delay"] = min(total["delay"], row["delay_ratio"])
        total["untrusted"] += row["baseline"] == "U"
        total["baselines"] += row["baseline"] != "-"
    print(f"\n{total['checks']} live checks on healthy plants: {total['flagged']} flagged, {total['events']} "
          f"structural events; longest misfit run {total['longest']} bins (flagged from adequacy.MISFIT_RUN_BINS only "
          "when no real extra mode explains it); the output error with a neighbouring delay was at least "
          f"{total['delay']:.2f} of the configured (true) delay's (flagged below adequacy.DELAY_ERROR_RATIO); "
          f"{total['untrusted']} of {total['baselines']} baselines learned untrusted (column base)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
