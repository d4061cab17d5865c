#!/usr/bin/env python3
"""CPU of the monitor while a fault test deviates, against healthy monitoring, on the same record.

While a test deviates the joint check refits every quarter memory (healthy: every two memory lengths), so the
decision costs more exactly when a fault is being confirmed. This streams a record with one modal change through
the monitor core in 0.1 s blocks (what the node's worker does) and prints, per phase, the process CPU per second of
data (cores needed at real time) and the slowest block (a latency the node's queue must absorb):

- healthy: from one memory length after the first monitoring report (the baseline learned, its one-time joint
  reference fit done) to the change;
- deviating: from the change to five memory lengths after it (the confirmation and the first checks after it).

    python scripts/bench_decision_cost.py [--case beam_gain2_-20%] [--repeat 3]
    python scripts/bench_decision_cost.py --campaign-seed 1057    # a fault-masking campaign run, --problem none
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from additive_rsrivc_ros.cli.evaluate import full_cases, simulate_case  # noqa: E402
from additive_rsrivc_ros.config import MonitorConfig  # noqa: E402
from additive_rsrivc_ros.core.monitor.pipeline import MonitorPipeline  # noqa: E402


@dataclass
class Record:
    label: str
    config: MonitorConfig
    t: np.ndarray
    r: np.ndarray
    u: np.ndarray
    y: np.ndarray
    t_change: float
    memory_s: float


def evaluate_case(label: str) -> Record:
    case = next((c for c in full_cases() if c.label == label), None)
    if case is None or (case.beam_change or case.paper_change) is None:
        raise SystemExit(f"--case must be an rsrivc_evaluate case with a modal change, got {label!r}")
    d = simulate_case(case)
    return Record(label, d.config, d.t, d.r, d.u, d.y, d.changes[0].start_s, max(m.memory_s for m in d.config.modes))


def campaign_run(seed: int) -> Record:
    """The run ``scripts/campaign_fault_masking.py --problem none --memory 0.5 3`` draws for this seed."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import campaign_fault_masking as camp

    run, params = camp.draw(seed, (0.5, 3.0), 5.0, "none")
    r, u, y, _ = camp.simulate_run(run, params, seed)
    excitation = "narrow" if run.narrow else "broad"
    change = f"m{run.change.mode + 1} {run.change.quantity} {run.change.relative_change:+.0%}"
    label = f"campaign seed {seed} --problem none ({len(run.modes)} modes, {excitation}, {change})"
    return Record(label, MonitorConfig.from_params(params), np.arange(r.size) / run.rate, r, u, y,
                  run.change.start_s, run.memory_s)


def one_run(data: Record, block_s: float) -> tuple[np.ndarray, np.ndarray, list, float]:
    """(block end times, CPU seconds per block, events, time of the first monitoring report) of one pass."""
    cfg = data.config
    pipe = MonitorPipeline(cfg)
    n = max(1, int(round(block_s * cfg.loop_rate_hz)))
    ends, cpu = [], []
    t_mon = float("inf")
    for k in range(0, data.t.size, n):
        c0 = time.process_time()
        reps = pipe.push(data.t[k:k + n], data.r[k:k + n], data.u[k:k + n], data.y[k:k + n])
        cpu.append(time.process_time() - c0)
        t_mon = min([t_mon] + [rep.time_s for rep in reps if rep.phase == "monitoring"])
        ends.append(float(data.t[min(k + n, data.t.size) - 1]))
    assert pipe.faults is not None
    return np.array(ends), np.array(cpu), list(pipe.faults.events), t_mon


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--case", default="beam_gain2_-20%", help="a case of rsrivc_evaluate with one modal change")
    ap.add_argument("--campaign-seed", type=int, help="instead, the fault-masking campaign's run of this seed with "
                    "--problem none")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--block-s", type=float, default=0.1)
    args = ap.parse_args(argv)
    data = campaign_run(args.campaign_seed) if args.campaign_seed is not None else evaluate_case(args.case)
    cfg = data.config
    memory = data.memory_s
    t_change = data.t_change
    print(f"{data.label}: {cfg.loop_rate_hz:g} Hz, K = {cfg.K}, memory {memory:g} s, change at {t_change:g} s; "
          f"{args.repeat} passes in {args.block_s:g} s blocks")
    print(f"{'pass':>4} {'healthy core':>13} {'deviating core':>15} {'ratio':>6} "
          f"{'slowest block healthy / dev (ms)':>34} {'alarm after (memory lengths)':>28}  slowest block of the run")
    for i in range(args.repeat):
        ends, cpu, events, t_base = one_run(data, args.block_s)
        healthy = (ends > t_base + memory) & (ends <= t_change)
        if not healthy.any():
            raise SystemExit("the change comes less than one memory length after monitoring starts: no healthy phase")
        dev = (ends > t_change) & (ends <= t_change + 5 * memory)
        c_h = cpu[healthy].sum() / (healthy.sum() * args.block_s)
        c_d = cpu[dev].sum() / (dev.sum() * args.block_s)
        alarm = min((e.alarm_time_s for e in events), default=float("nan"))
        worst = int(np.argmax(cpu))
        print(f"{i + 1:>4} {c_h:>13.3f} {c_d:>15.3f} {c_d / c_h:>6.2f} "
              f"{1e3 * cpu[healthy].max():>16.1f} / {1e3 * cpu[dev].max():<15.1f} {(alarm - t_change) / memory:>28.2f}"
              f"  {1e3 * cpu[worst]:.0f} ms at {ends[worst]:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
