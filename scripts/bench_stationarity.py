#!/usr/bin/env python3
"""``rsrivc_identify --modes auto`` on a 240 s record against the same fit on half of it (paired, interleaved).

    python scripts/bench_stationarity.py [--pairs 3] [--duration 240] [--change -0.03] [--seed 1] [--dir DIR] [--read]

The record: the 4 kHz closed loop with the close pair of modes 62 / 71 Hz (additive_rsrivc_ros.sim.experiments
close_pair_record); ``--change`` moves mode 3's natural frequency by that fraction at the middle (0: stationary).
Each pair runs the whole record and ``--end <middle>`` as separate processes, in alternating order; CPU seconds
(user + system of the child, what the shared machine's load does not inflate) and wall seconds are printed per run,
then the medians and the ratio whole / half. ``--read``: instead, the reader's CPU and wall seconds for the whole
record, 10 s of it and its first half (``--start``/``--end`` skip the rest at the reader), three rounds.
Run it with ``scripts/env.sh`` sourced.
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

from additive_rsrivc_ros.io.bagio import write_bag
from additive_rsrivc_ros.sim.experiments import CLOSE_PAIR_RATE_HZ, close_pair_params_yaml, close_pair_record
from additive_rsrivc_ros.sim.simulate import ModalChange


def _run(argv: list[str]) -> tuple[float, float, dict]:
    """CPU and wall seconds of one ``rsrivc_identify`` process, and its JSON."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.monotonic()
    subprocess.run(["rsrivc_identify", *argv], check=True, stdout=subprocess.DEVNULL)
    wall = time.monotonic() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    out = argv[argv.index("--out") + 1]
    return cpu, wall, json.loads(Path(out).read_text())


def _read_figures(bag: Path, params: Path, duration: float) -> None:
    from additive_rsrivc_ros.config import load_config
    from additive_rsrivc_ros.io.bagio import read_signals
    from additive_rsrivc_ros.io.timerange import TimeRange

    cfg = load_config(params)
    read_signals(bag, cfg, TimeRange(0.0, 1.0))        # imports and compiled kernels
    ranges = {"whole": None, "10 s": TimeRange(duration / 2 - 20.0, duration / 2 - 10.0),
              "first half": TimeRange(None, duration / 2)}
    for _ in range(3):
        for name, rng in ranges.items():
            c, w = time.process_time(), time.perf_counter()
            n = read_signals(bag, cfg, rng).n
            print(f"read {name:10s} {n:8d} samples: cpu {time.process_time() - c:.3f} s  wall "
                  f"{time.perf_counter() - w:.3f} s", flush=True)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--pairs", type=int, default=3)
    p.add_argument("--duration", type=float, default=240.0)
    p.add_argument("--change", type=float, default=-0.03, help="mode 3 frequency change at the middle (0: none)")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--dir", default=None, help="working directory (default: a temporary one)")
    p.add_argument("--read", action="store_true", help="time the reader with and without a range instead")
    a = p.parse_args()
    work = Path(a.dir or tempfile.mkdtemp(prefix="bench_stationarity_"))
    work.mkdir(parents=True, exist_ok=True)
    bag = work / f"record_{a.seed}_{a.change:+g}"
    params = work / "params.yaml"
    params.write_text(close_pair_params_yaml())
    if not bag.exists():
        changes = (ModalChange(2, "frequency", a.change, a.duration / 2),) if a.change else ()
        sim = close_pair_record(a.seed, a.duration, changes)
        write_bag(bag, CLOSE_PAIR_RATE_HZ, sim.u, sim.y, sim.r)
    if a.read:
        _read_figures(bag, params, a.duration)
        return
    base = [str(bag), "--params-file", str(params), "--modes", "auto"]
    runs = {"whole": [*base, "--out", str(work / "whole.json")],
            "half": [*base, "--end", f"{a.duration / 2:g}", "--out", str(work / "half.json")]}
    cpu: dict[str, list[float]] = {"whole": [], "half": []}
    wall: dict[str, list[float]] = {"whole": [], "half": []}
    for i in range(a.pairs):
        for name in (("whole", "half") if i % 2 == 0 else ("half", "whole")):
            c, w, doc = _run(runs[name])
            cpu[name].append(c)
            wall[name].append(w)
            print(f"pair {i + 1} {name:5s}: cpu {c:6.2f} s  wall {w:6.2f} s  stationary {doc.get('stationary')}  "
                  f"converged {doc['converged']}  K {len(doc['modes'])}  fitted {doc.get('fitted_s')}", flush=True)
    med = {k: (statistics.median(cpu[k]), statistics.median(wall[k])) for k in cpu}
    print(f"median cpu: whole {med['whole'][0]:.2f} s, half {med['half'][0]:.2f} s, ratio "
          f"{med['whole'][0] / med['half'][0]:.2f}; median wall: whole {med['whole'][1]:.2f} s, half "
          f"{med['half'][1]:.2f} s, ratio {med['whole'][1] / med['half'][1]:.2f}")


if __name__ == "__main__":
    main()
