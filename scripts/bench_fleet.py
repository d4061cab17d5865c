#!/usr/bin/env python3
"""Fleet throughput of ``rsrivc_fleet``: bags per minute with 1 worker vs all workers on the same 8 bags.

    python scripts/bench_fleet.py [--bags 8] [--duration 10] [--workers N] [--no-report] [--json]

The bags are simulated recordings of one machine (additive_rsrivc_ros.sim.fleetsim: open loop, 1 kHz, 2 modes); each
task is the full ``rsrivc_diagnose`` of one bag (report included unless --no-report). The figure comes from
:func:`additive_rsrivc_ros.cli.fleet.throughput` (``rsrivc_bench --json`` key ``fleet``). Run it with
``scripts/env.sh`` sourced (one BLAS thread per worker, the shared numba cache).
"""

from __future__ import annotations

import argparse
import json

from additive_rsrivc_ros.cli.fleet import throughput


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--bags", type=int, default=8)
    p.add_argument("--duration", type=float, default=10.0, help="seconds per simulated bag")
    p.add_argument("--workers", type=int, default=None, help="default: the CPUs available to this process")
    p.add_argument("--no-report", action="store_true", help="per-bag CSV/JSON only (no report.html)")
    p.add_argument("--json", action="store_true", help="print the rsrivc_bench 'fleet' object only")
    a = p.parse_args()
    res = throughput(a.bags, a.duration, a.workers, report=not a.no_report)
    if a.json:
        print(json.dumps({"fleet": res}))
        return
    print(f"rsrivc_fleet throughput, {a.bags} bags of {a.duration:g} s (1 kHz, K = 2"
          f"{', report included' if not a.no_report else ', no report'}):")
    print(f"  1 worker : {res['bags_per_min_1_worker']:6.1f} bags/min")
    print(f"  {res['workers']} workers: {res['bags_per_min_all_workers']:6.1f} bags/min "
          f"(x{res['bags_per_min_all_workers'] / res['bags_per_min_1_worker']:.2f})")


if __name__ == "__main__":
    main()
