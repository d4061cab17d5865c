#!/usr/bin/env python3
"""Print what the controller-invariant stream aligner (core/input/alignment.py) does on the bundled beam_fault record.

For each data fault (a message lost or repeated on one stream, early / in the baseline window / after the fault,
1 % random loss, a 5 % wrong controller, feedforward) it prints the aligner's counters, the number of released
samples that violate the invariant (misaligned), and the pipeline's verdict on the -5 % mode-2 frequency fault at
20 s; then the aligner's cost per sample. Run: ``python scripts/study_alignment.py [--quick]``.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from additive_rsrivc_ros.config import MonitorConfig, load_params_file
from additive_rsrivc_ros.core.controller import DiscreteController
from additive_rsrivc_ros.core.input.alignment import InvariantAligner, align_record, invariant_residual
from additive_rsrivc_ros.core.monitor.pipeline import MonitorPipeline
from additive_rsrivc_ros.io.bagio import read_signals

REPO = Path(__file__).resolve().parents[1]


def perturb(sig, stream: str, op: str, k: int) -> tuple[np.ndarray, ...]:
    x = {"r": sig.r, "u": sig.u, "y": sig.y}
    x[stream] = np.delete(x[stream], k) if op == "lost" else np.insert(x[stream], k, x[stream][k])
    n = min(v.size for v in x.values())
    return sig.t[:n], x["r"][:n], x["u"][:n], x["y"][:n]


def violations(ctrl: DiscreteController, r, u, y) -> int:
    e, scale = invariant_residual(ctrl.den, ctrl.num, r, u, y)
    ok = np.isfinite(e)
    return int(np.count_nonzero(np.abs(e[ok]) > 1e-9 * scale[ok]))


def verdict(cfg, t, r, u, y) -> str:
    pipe = MonitorPipeline(cfg)
    for a in range(0, t.size, 4096):
        pipe.push(t[a:a + 4096], r[a:a + 4096], u[a:a + 4096], y[a:a + 4096])
    pipe.flush()
    ev = sorted({(e.mode, e.quantity, e.direction) for e in pipe.faults.events})
    return ", ".join(f"m{m} {q} {d}" for m, q, d in ev) or "no event"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="aligner counters only (no pipeline verdicts)")
    args = ap.parse_args()
    cfg = MonitorConfig.from_params(load_params_file(REPO / "config/beam_fault.yaml"))
    sig = read_signals(REPO / "bags/beam_fault", cfg)
    rate, ctrl = cfg.loop_rate_hz, cfg.controller
    cases: list[tuple[str, tuple, DiscreteController | None]] = [("clean", (sig.t, sig.r, sig.u, sig.y), ctrl)]
    for stream in "ruy":
        for op in ("lost", "repeated"):
            for k, where in ((50, "0.01 s"), (int(12.2 * rate), "12.2 s"), (22 * int(rate), "22 s")):
                cases.append((f"{stream} {op} at {where}", perturb(sig, stream, op, k), ctrl))
    rng = np.random.default_rng(1)
    lost = np.sort(rng.choice(np.arange(100, sig.u.size), size=sig.u.size // 100, replace=False))
    u1 = np.delete(sig.u, lost)
    cases.append(("u 1 % random loss", (sig.t[:u1.size], sig.r[:u1.size], u1, sig.y[:u1.size]), ctrl))
    wrong = DiscreteController(tuple(1.05 * np.asarray(ctrl.numerator)), ctrl.denominator)
    cases.append(("controller 5 % off (aligned data)", (sig.t, sig.r, sig.u, sig.y), wrong))
    cases.append(("feedforward 0.3 r (aligned data)", (sig.t, sig.r, sig.u + 0.3 * sig.r, sig.y), None))
    hdr = (f"{'case':36s} {'realign':>7s} {'refill':>6s} {'surplus':>7s} {'aside':>5s} {'late':>4s} "
           f"{'misaligned':>10s} {'rel.resid':>9s}  verdict (truth: m2 natural_frequency down)")
    print(hdr)
    print("-" * len(hdr))
    for name, (t, r, u, y), c in cases:     # c None: the plant's controller, but u is not C_d(r - y) exactly
        blk, st = align_record(c or ctrl, rate, t, r, u, y)
        bad = violations(c, blk.r, blk.u, blk.y) if c is ctrl else -1
        v = "" if args.quick or c is wrong else verdict(cfg, t, r, u, y)
        print(f"{name:36s} {st.realignments:7d} {st.reconstructed:6d} {st.surplus:7d} "
              f"{st.invalidated + st.late:5d} {st.late:4d} {bad if bad >= 0 else 'n/a':>10} "
              f"{st.relative_residual:9.1e}  {v}")
    for block in (8, 410, None):
        al = InvariantAligner(ctrl, rate, lag=33)
        al.push(sig.t[:64], sig.r[:64], sig.u[:64], sig.y[:64])
        step = block or sig.t.size
        t0 = time.perf_counter()
        for a in range(64, sig.t.size, step):
            al.push(sig.t[a:a + step], sig.r[a:a + step], sig.u[a:a + step], sig.y[a:a + step])
        al.flush()
        us = (time.perf_counter() - t0) / (sig.t.size - 64) * 1e6
        print(f"aligner cost, blocks of {block or 'all'} samples: {us:.2f} us per sample "
              f"({us * rate * 1e-6:.1%} of a core at {rate:g} Hz)")


if __name__ == "__main__":
    main()
