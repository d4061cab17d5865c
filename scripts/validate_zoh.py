"""Validate ``core.zoh.second_order_zoh`` against an extended-precision reference over the admissible domain.

``python scripts/validate_zoh.py [--n 100000] [--seed 0]`` prints the max error table per regime; the reference, the
error measure and the sampling of the domain are in additive_rsrivc_ros/sim/zoh_reference.py.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from additive_rsrivc_ros.sim.zoh_reference import CLASS_NAMES, PREC, errors, sample_iterates


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=100_000)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    pts, cls = sample_iterates(args.n, args.seed)
    t0 = time.perf_counter()
    err, fin = errors(pts)
    dt = time.perf_counter() - t0
    print(f"second_order_zoh vs decimal ({PREC} digits) reference: {args.n} random admissible iterates, seed "
          f"{args.seed}, {dt:.0f} s")
    print(f"{'class':<18} {'n':>7} {'non-finite':>10} {'max err':>10} {'99.9 %':>10} {'median':>10}")
    for c, name in enumerate(CLASS_NAMES):
        m = cls == c
        if np.any(m):
            print(f"{name:<18} {m.sum():>7d} {np.sum(~fin[m]):>10d} {err[m].max():>10.2e} "
                  f"{np.quantile(err[m], 0.999):>10.2e} {np.median(err[m]):>10.2e}")
    print(f"{'all':<18} {len(err):>7d} {np.sum(~fin):>10d} {err.max():>10.2e} {np.quantile(err, 0.999):>10.2e} "
          f"{np.median(err):>10.2e}")
    worst = int(np.argmax(err))
    print(f"worst: a1={pts[worst, 0]!r} a2={pts[worst, 1]!r} h={pts[worst, 2]!r} err={err[worst]:.3e}")
    return 0 if (np.all(fin) and err.max() <= 1e-9) else 1


if __name__ == "__main__":
    raise SystemExit(main())
