#!/usr/bin/env python3
"""Fault-masking campaign: can a data problem just before a real change hide it, or blame the wrong mode?

Each run draws a random plant and loop from the simulator (1-4 modes, 1-8 kHz, PI controller designed to a modulus
margin, broadband excitation: square wave plus white dither, or narrow: four reference lines and no dither), a
memory length, and a relevant change (a random mode and quantity, 2-4x its ``faults.min_change``, up or down) at a
random time after the baseline is in place. Before the change, at a random distance down to a fraction of a memory,
it applies one data problem:

``none`` | ``glitch`` (output + 5 noise std for 10 ms) | ``nan`` (40 NaN outputs) | ``lost`` (one output sample lost,
the rest shifted) | ``duplicate`` (one sample recorded twice) | ``clock_back`` / ``clock_fwd`` (every stamp after
it shifted by -/+ 0.5 sample) | ``pause`` (two memory lengths with no samples) | ``restart`` (the pipeline saved,
dropped and restored from its state, 1 s of data lost) | ``weak_mode`` (the plant has one more mode, not modelled
and weakly excited, from the start).

Invariant per run (the monitor's promise): no event on a quantity that did not change, and the change flagged on
the right mode, quantity and direction within ``--bound`` memory lengths of testable time after max(change, end of
the problem) (time the verdict lists as blind for that mode, e.g. a re-initialization, does not count); or the
verdict is not OK and the changed mode's blind time (global or its own) covers part of that interval.

Prints one row per run, the violations with their reason, the detection delays in memory lengths (median, worst
five) and the counts. Usage::

    python scripts/campaign_fault_masking.py [--runs 300] [--seed 0] [--memory 1 50] [--bound 5] [--param N=V]

Heavy: a run simulates ~15 memory lengths of data (a 50 s memory at 8 kHz is 6 M samples); ``--memory 0.5 3`` and
fewer runs give a quick look.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from validate_autostart import design_controller, random_plant  # noqa: E402

from additive_rsrivc_ros.config import MonitorConfig  # noqa: E402
from additive_rsrivc_ros.core.monitor.pipeline import MonitorPipeline  # noqa: E402
from additive_rsrivc_ros.core.vocabulary import QUANTITIES  # noqa: E402
from additive_rsrivc_ros.outputs.verdict import assess  # noqa: E402
from additive_rsrivc_ros.sim.simulate import (  # noqa: E402
    ModalChange,
    PlantMode,
    simulate_modes,
    square_wave,
    sum_of_sines,
    white_noise,
)

PROBLEMS = ("none", "glitch", "nan", "lost", "duplicate", "clock_back", "clock_fwd", "pause", "restart", "weak_mode")
SIM_QUANTITY = {"natural_frequency": "frequency", "damping": "damping", "gain": "gain"}
MIN_CHANGE = {"natural_frequency": 0.02, "damping": 0.20, "gain": 0.10}   # faults.min_change.* defaults


@dataclass
class Run:
    seed: int
    rate: float
    modes: list[PlantMode]
    memory_s: float
    narrow: bool
    problem: str
    change: ModalChange
    quantity: str
    t_problem: float
    t_ref: float            # max(change, end of the problem)
    duration: float


def draw(seed: int, mem_range: tuple[float, float], bound: float, problem: str | None) -> tuple[Run, dict]:
    """A random run: plant, loop, memory, change and data problem; and the monitor's flat parameters."""
    rng = np.random.default_rng(seed)
    modes, rate, delay = random_plant(rng)
    ctrl = design_controller(modes, rate, delay)
    f1 = modes[0].natural_frequency_hz
    # a memory long enough for the lowest mode's dynamics (several periods and its decay time)
    t_min = max(mem_range[0], 10.0 / f1, max(2.0 / (m.damping_ratio * 2 * math.pi * m.natural_frequency_hz)
                                             for m in modes))
    memory = float(np.exp(rng.uniform(math.log(t_min), math.log(max(t_min, mem_range[1])))))
    narrow = bool(rng.random() < 0.3)
    problem = problem or str(rng.choice(PROBLEMS))
    i = int(rng.integers(len(modes)))
    q = str(rng.choice(QUANTITIES))
    size = float(rng.uniform(2.0, 4.0)) * MIN_CHANGE[q] * float(rng.choice([-1.0, 1.0]))
    init = max(4.0, 2.0 * memory)
    t_base = init + (3.0 + 5.0) * memory          # settle + baseline window (defaults)
    t_change = t_base + float(rng.uniform(1.0, 3.0)) * memory
    t_problem = t_change - float(rng.uniform(0.05, 2.0)) * memory
    t_end_problem = t_problem + (2.0 * memory if problem == "pause" else 1.0 if problem == "restart" else 0.0)
    t_ref = max(t_change, t_end_problem)
    duration = t_ref + (bound + 1.0) * memory
    if problem == "weak_mode":
        f_hi = min(1000.0, rate / 5.0)
        f_x = float(np.exp(rng.uniform(math.log(f1 * 1.3), math.log(max(f1 * 1.4, f_hi)))))
        modes = [*modes, PlantMode(f_x, 0.02, 1e-3 * min(m.gain for m in modes))]
    change = ModalChange(i, SIM_QUANTITY[q], size, t_change)
    run = Run(seed, rate, modes, memory, narrow, problem, change, q, t_problem, t_ref, duration)
    k = len(modes) - (problem == "weak_mode")
    params = {"loop_rate_hz": rate, "closed_loop": True, "controller.numerator": list(ctrl.num),
              "controller.denominator": list(ctrl.den), "input_delay_samples": delay,
              "modes.natural_frequency_hz": [m.natural_frequency_hz for m in modes[:k]],
              "modes.damping_ratio": [m.damping_ratio for m in modes[:k]],
              "modes.gain": [m.gain for m in modes[:k]], "modes.memory_s": [memory] * k,
              "init_duration_s": init, "publish_rate_hz": max(10.0, 20.0 / memory)}
    return run, params


def excitation(run: Run, rng: np.random.Generator) -> np.ndarray:
    t = np.arange(int(run.duration * run.rate)) / run.rate
    f1 = run.modes[0].natural_frequency_hz
    if run.narrow:    # four reference lines around the modes, no dither (the closed-loop study of the papers)
        lines = sorted({min(m.natural_frequency_hz * rng.uniform(0.6, 1.4), run.rate / 5) for m in run.modes})
        lines = (lines + [f1 * 0.3, f1 * 2.5, f1 * 0.7])[:4]
        return sum_of_sines(t, [1.0] * len(lines), [2 * math.pi * f for f in lines])
    sq = square_wave(t, min(2.0, f1 / 5.0), 1.0)
    return sq + white_noise(t.size, 0.05, rng)


def damage(run: Run, t: np.ndarray, r: np.ndarray, u: np.ndarray, y: np.ndarray, noise_std: float):
    """The data problem on the recorded stream (stamps in seconds)."""
    k = int(np.searchsorted(t, run.t_problem))
    h = 1.0 / run.rate
    t, r, u, y = t.copy(), r.copy(), u.copy(), y.copy()
    if run.problem == "glitch":
        y[k:k + max(1, int(0.01 * run.rate))] += 5.0 * noise_std
    elif run.problem == "nan":
        y[k:k + 40] = np.nan
    elif run.problem == "lost":
        y = np.delete(y, k)
        t, r, u = t[:-1], r[:-1], u[:-1]
    elif run.problem == "duplicate":
        t, r, u, y = (np.insert(x, k + 1, x[k]) for x in (t, r, u, y))
    elif run.problem in ("clock_back", "clock_fwd"):
        t[k:] += (-0.5 if run.problem == "clock_back" else 0.5) * h
    elif run.problem == "pause":
        keep = (t < run.t_problem) | (t >= run.t_problem + 2.0 * run.memory_s)
        t, r, u, y = t[keep], r[keep], u[keep], y[keep]
    return t, r, u, y


def monitor(run: Run, cfg: MonitorConfig, t, r, u, y) -> list:
    pipe = MonitorPipeline(cfg)
    n = max(1, int(cfg.loop_rate_hz / 10))
    reps: list = []
    a = 0
    restarted = run.problem != "restart"
    while a < t.size:
        if not restarted and t[a] >= run.t_problem:
            state = pipe.get_state()          # the node saved its state, was killed, and restarts 1 s later
            pipe = MonitorPipeline(cfg, state=state)
            a = int(np.searchsorted(t, run.t_problem + 1.0))
            restarted = True
            continue
        reps += pipe.push(t[a:a + n], r[a:a + n], u[a:a + n], y[a:a + n])
        a += n
    return reps + pipe.flush()


def _covered_s(intervals: list, a: float, b: float) -> float:
    """Seconds of ``[a, b]`` covered by the union of ``intervals`` (each with ``start_s``, ``end_s``)."""
    spans = sorted((max(i.start_s, a), min(i.end_s, b)) for i in intervals if i.end_s > a and i.start_s < b)
    total, end = 0.0, a
    for lo, hi in spans:
        lo = max(lo, end)
        if hi > lo:
            total, end = total + hi - lo, hi
    return total


def judge(run: Run, reps: list, bound: float) -> tuple[str, float | None, str]:
    """(result, delay in memory lengths, why): result ``ok``, ``blind`` (not detected, honestly not OK) or
    ``VIOLATION``."""
    events = [e for rep in reps for e in rep.events_opened]
    right_dir = "up" if run.change.relative_change > 0 else "down"
    wrong = [e for e in events if not (e.mode == run.change.mode + 1 and e.quantity == run.quantity)]
    if wrong:
        e = wrong[0]
        return "VIOLATION", None, f"event on mode {e.mode} {e.quantity} {e.direction} at {e.alarm_time_s:.1f} s"
    hits = [e for e in events if e.direction == right_dir]
    verdict = assess(reps, run.duration)
    mode_blind = verdict.mode_blind.get(run.change.mode + 1, [])
    blind = [b for b in [*verdict.blind_intervals, *mode_blind] if not b.startup]
    if hits:
        delay = (hits[0].alarm_time_s - run.t_ref) / run.memory_s
        if delay <= bound:
            return "ok", delay, ""
        # the bound counts testable time: the verdict lists the changed mode's blind time (e.g. a re-initialization
        # after the change made the model invalid) and the alarm came within the bound of the time it was tested
        held = _covered_s(blind, run.t_ref, hits[0].alarm_time_s) / run.memory_s
        if delay - held <= bound:
            why = max(blind, key=lambda b: _covered_s([b], run.t_ref, hits[0].alarm_time_s)).reason
            return "ok", delay, f"{held:.1f} memory lengths of it blind ({why[:60]})"
        return "VIOLATION", delay, f"late: {delay:.1f} memory lengths ({held:.1f} of them blind)"
    if [e for e in events if e.direction != right_dir]:
        return "VIOLATION", None, "event in the wrong direction"
    window = (run.t_ref, run.t_ref + bound * run.memory_s)
    covered = [b for b in blind if b.start_s < window[1] and b.end_s > window[0]]
    if verdict.level != "OK" and covered:
        return "blind", None, f"{verdict.level}: {covered[0].reason[:80]}"
    return "VIOLATION", None, f"missed; verdict {verdict.level}: {verdict.text[:120]}"


def simulate_run(run: Run, params: dict, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """The closed loop of a drawn run before any data problem: r, u, y (output noise 1 % of the clean output's
    std) and that noise std."""
    rng = np.random.default_rng(seed + 10_000)
    r = excitation(run, rng)
    from additive_rsrivc_ros.core.controller import DiscreteController
    ctrl = DiscreteController(tuple(params["controller.numerator"]), tuple(params["controller.denominator"]))
    clean = simulate_modes(run.modes, run.rate, r=r, controller=ctrl, input_delay=params["input_delay_samples"],
                           changes=[run.change])
    noise_std = 0.01 * float(np.std(clean.y)) or 1e-6
    sim = simulate_modes(run.modes, run.rate, r=r, controller=ctrl, input_delay=params["input_delay_samples"],
                         changes=[run.change], noise=white_noise(r.size, noise_std, rng))
    return r, sim.u, sim.y, noise_std


def one(seed: int, args: argparse.Namespace) -> tuple[Run, str, float | None, str, float]:
    t0 = time.perf_counter()
    run, params = draw(seed, tuple(args.memory), args.bound, args.problem)
    for item in args.param or []:
        name, _, value = item.partition("=")
        params[name] = float(value)
    r, u, y, noise_std = simulate_run(run, params, seed)
    t = np.arange(r.size) / run.rate
    t, rr, u, y = damage(run, t, r, u, y, noise_std)
    cfg = MonitorConfig.from_params(params)
    reps = monitor(run, cfg, t, rr, u, y)
    res, delay, why = judge(run, reps, args.bound)
    return run, res, delay, why, time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=300)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--memory", type=float, nargs=2, default=(1.0, 50.0), metavar=("MIN_S", "MAX_S"))
    ap.add_argument("--bound", type=float, default=5.0, help="detection bound in memory lengths (default 5)")
    ap.add_argument("--seeds", type=int, nargs="+", metavar="SEED",
                    help="run exactly these seeds (e.g. the slow ones of a campaign) instead of --runs from --seed")
    ap.add_argument("--problem", choices=PROBLEMS, help="only this data problem")
    ap.add_argument("--param", action="append", metavar="NAME=VALUE",
                    help="a numeric monitor parameter for every run (repeatable), e.g. faults.fast.memory_fraction=1 "
                         "for the alarm delays without the fast tracking")
    args = ap.parse_args()
    print(f"{'seed':>5} {'K':>2} {'rate':>5} {'mem s':>6} {'exc':6} {'problem':10} {'change':28} {'before':>6} "
          f"{'result':9} {'delay':>5}  why")
    delays: list[tuple[float, int, str]] = []
    counts: dict[str, int] = {}
    for seed in args.seeds or range(args.seed, args.seed + args.runs):
        try:
            run, res, delay, why, secs = one(seed, args)
        except RuntimeError as exc:       # no stabilizing controller for this draw: not a run
            print(f"{seed:5d} skipped: {exc}")
            continue
        counts[res] = counts.get(res, 0) + 1
        c = run.change
        ch = f"m{c.mode + 1} {run.quantity[:9]} {100 * c.relative_change:+.0f}%"
        before = (c.start_s - run.t_problem) / run.memory_s
        print(f"{seed:5d} {len(run.modes):2d} {run.rate:5.0f} {run.memory_s:6.2f} "
              f"{'narrow' if run.narrow else 'broad':6} {run.problem:10} {ch:28} {before:6.2f} {res:9} "
              f"{'' if delay is None else f'{delay:5.2f}':>5}  {why} ({secs:.0f} s)", flush=True)
        if delay is not None:
            delays.append((delay, seed, run.problem))
    n = sum(counts.values())
    print(f"\n{n} runs: " + ", ".join(f"{k} {v}" for k, v in sorted(counts.items())))
    if delays:
        d = sorted(delays)
        print("detection delay after max(change, end of problem), memory lengths: median "
              f"{np.median([x[0] for x in d]):.2f}; worst: "
              + ", ".join(f"{x:.2f} (seed {s}, {p})" for x, s, p in d[-5:][::-1]))
    by_problem: dict[str, list[float]] = {}
    for x, _, p in delays:
        by_problem.setdefault(p, []).append(x)
    if by_problem:
        print("median / worst delay per data problem: " + ", ".join(
            f"{p} {np.median(v):.2f} / {max(v):.2f} ({len(v)})" for p, v in sorted(by_problem.items())))
    print(f"violations: {counts.get('VIOLATION', 0)} of {n}")


if __name__ == "__main__":
    main()
