#!/usr/bin/env python3
"""Does ``rsrivc_identify`` call healthy records stationary, and changed ones not? Seeds x scenarios, a table.

    python scripts/study_stationarity.py [--seeds 3] [--duration 120] [--cases beam_healthy,open_loop_multisine,...]

Each case is a simulated record with known truth, identified from its params file's guesses (the shipped scenarios:
``beam_healthy`` 4096 Hz with K = 2 of 4 modes, ``open_loop_multisine`` 1 kHz with ARMA output noise,
``rigid_body`` 1 kHz with a double integrator) or found with ``--modes auto`` (``close_pair``: the 62 / 71 Hz loop
at 2 kHz, healthy; ``close_pair_step``: mode 3 -3 % at the middle; ``close_pair_gain``: mode 2 gain -25 %). Prints
per case the calls (stationary / not / not tested) and the largest |z| of any segment difference; a healthy case
should be stationary in every seed (Bonferroni: at most 1 % of records otherwise), a changed one never.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import tempfile
from pathlib import Path

from additive_rsrivc_ros.cli import identify
from additive_rsrivc_ros.io.bagio import write_bag
from additive_rsrivc_ros.sim.experiments import close_pair_params_yaml, close_pair_record
from additive_rsrivc_ros.sim.scenarios import build
from additive_rsrivc_ros.sim.simulate import ModalChange

CLOSE = {"close_pair": (), "close_pair_step": (ModalChange(2, "frequency", -0.03, 0.5),),
         "close_pair_gain": (ModalChange(1, "gain", -0.25, 0.5),)}


def _record(case: str, seed: int, duration: float, work: Path) -> tuple[Path, Path, list[str]]:
    bag, params = work / f"{case}_{seed}", work / f"{case}.yaml"
    if case in CLOSE:
        changes = tuple(ModalChange(c.mode, c.quantity, c.relative_change, c.start_s * duration) for c in CLOSE[case])
        sim = close_pair_record(seed, duration, changes, rate_hz=2000.0)
        write_bag(bag, 2000.0, sim.u, sim.y, sim.r)
        params.write_text(close_pair_params_yaml(rate_hz=2000.0))
        return bag, params, ["--modes", "auto"]
    data = build(case, duration_s=duration, seed=seed)
    data.write_bag(bag)
    return bag, data.config_path, []


def _max_z(doc: dict) -> float:
    """The largest |z| between consecutive segments' modal values (the statistic the test thresholds)."""
    segs = [s for s in doc["stationarity"]["segments"] if s.get("usable")]
    best = 0.0
    for a, b in zip(segs, segs[1:], strict=False):
        for ma, mb in zip(a["modes"], b["modes"], strict=True):
            for k in ("natural_frequency_hz", "damping_ratio", "gain"):
                s = (ma[f"{k}_std"] ** 2 + mb[f"{k}_std"] ** 2) ** 0.5
                if s > 0:
                    best = max(best, abs(ma[k] - mb[k]) / s)
    return best


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=3)
    p.add_argument("--duration", type=float, default=120.0)
    p.add_argument("--cases", default="beam_healthy,open_loop_multisine,rigid_body,close_pair,close_pair_step,"
                                      "close_pair_gain")
    a = p.parse_args()
    work = Path(tempfile.mkdtemp(prefix="study_stationarity_"))
    print(f"{'case':22s} {'seed':>4s}  {'stationary':10s} {'max |z|':>8s} {'z_crit':>6s}  message")
    for case in a.cases.split(","):
        for seed in range(a.seeds):
            bag, params, extra = _record(case, seed, a.duration, work)
            out = work / f"{case}_{seed}.json"
            with contextlib.redirect_stdout(io.StringIO()):      # the table only
                code = identify.main([str(bag), "--params-file", str(params), "--out", str(out), *extra])
            if code != 0:
                print(f"{case:22s} {seed:4d}  exit {code}")
                continue
            doc = json.loads(out.read_text())
            st = doc["stationarity"]
            print(f"{case:22s} {seed:4d}  {str(doc['stationary']):10s} {_max_z(doc):8.2f} "
                  f"{st['z_crit'] or float('nan'):6.2f}  {st['message'][:110]}", flush=True)


if __name__ == "__main__":
    main()
