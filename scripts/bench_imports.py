"""What the hand-written peak finder (core/modefind.peak_prominences) saves, what the diagnosis path imports, and what
a report's numbers cost.

``python scripts/bench_imports.py [--runs N]`` prints, per scipy subpackage, the seconds a fresh interpreter (numpy
already imported) needs to import it (median and range of N processes), then the scipy subpackages a fresh
``rsrivc_diagnose`` process of 60 s of 4096 Hz beam data (K = 2, config/beam_fault.yaml) has imported at its end.
``scipy.signal.find_peaks`` would add its import to every diagnosis, node start and automatic start; the test that
the peak finder equals it is test/test_modefind.py. Last, the microseconds of one report's numbers
(:func:`.report_numbers.report_numbers`, K = 2 beam modes). Run on an otherwise idle machine.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

MODULES = ("scipy.special", "scipy.linalg", "scipy.signal")
_IMPORT = ("import time, importlib, numpy\nt = time.perf_counter()\nimportlib.import_module({name!r})\n"
           "print(time.perf_counter() - t)\n")
_DIAGNOSE = """
import sys, json
from additive_rsrivc_ros.cli import diagnose
diagnose.main([{bag!r}, "--params-file", {params!r}, "--out", {out!r}, "--quiet", "--no-progress"])
print(json.dumps(sorted(m for m in sys.modules if m.startswith("scipy.") and m.count(".") == 1)))
"""


def import_seconds(name: str, runs: int) -> list[float]:
    """Seconds to import ``name`` in ``runs`` fresh interpreters (numpy already imported)."""
    return [float(subprocess.run([sys.executable, "-c", _IMPORT.format(name=name)], capture_output=True, text=True,
                                 check=True).stdout.split()[-1]) for _ in range(runs)]


def diagnosis_imports() -> list[str]:
    """The scipy subpackages a fresh 60 s diagnosis has imported."""
    from additive_rsrivc_ros.sim.scenarios import build, config_dir

    with tempfile.TemporaryDirectory(prefix="rsrivc-imports-") as tmp:
        bag = Path(tmp) / "beam"
        build("beam_fault", duration_s=60.0, seed=1).write_bag(bag)
        code = _DIAGNOSE.format(bag=str(bag), params=str(config_dir() / "beam_fault.yaml"), out=str(Path(tmp) / "o"))
        res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
        return json.loads(res.stdout.strip().splitlines()[-1])


def report_microseconds(calls: int = 2000) -> tuple[float, float]:
    """Best and median over 7 rounds of the microseconds per :func:`.report_numbers.report_numbers` call (K = 2)."""
    import time

    import numpy as np

    from additive_rsrivc_ros.core.estimation.recursive import COVARIANCE_REL_TOL, RecursiveAdditiveSRIVC
    from additive_rsrivc_ros.core.estimation.report_numbers import report_numbers
    from additive_rsrivc_ros.core.model import SubmodelStructure
    from additive_rsrivc_ros.sim.plants import BEAM_THETAS, beam_controller

    est = RecursiveAdditiveSRIVC([SubmodelStructure()] * 2, [t * 1.01 for t in BEAM_THETAS[:2]], 4096.0,
                                 forgetting=0.9999, controller=beam_controller(4096.0), input_delay=4)
    t = np.arange(8192) / 4096.0
    r = 1e-3 * np.sign(np.sin(2 * np.pi * 2 * t + 1e-9))
    est.update(r, r * 0.1, r * 0.01)
    st = est.get_state()
    out = (np.zeros((2, 3, 3)), np.zeros((2, 3, 3)), np.zeros(2, dtype=np.int64), np.zeros(2, dtype=np.int64),
           np.empty((2, 6)), np.empty(2), np.empty(2))
    args = (st["kind"], st["theta"], st["P"], st["S"], 1e-6, COVARIANCE_REL_TOL, *out)
    report_numbers(*args)
    rounds = []
    for _ in range(7):
        t0 = time.perf_counter()
        for _ in range(calls):
            report_numbers(*args)
        rounds.append((time.perf_counter() - t0) / calls * 1e6)
    return min(rounds), statistics.median(rounds)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5, help="fresh processes per module (default 5)")
    args = ap.parse_args()
    for name in MODULES:
        v = import_seconds(name, args.runs)
        print(f"import {name:14s} median {statistics.median(v):.3f} s  ({min(v):.3f}-{max(v):.3f}, {len(v)} runs)")
    print("a 60 s diagnosis imports:", ", ".join(diagnosis_imports()) or "no scipy subpackage")
    best, median = report_microseconds()
    print(f"one report's numbers (K = 2): best {best:.1f} us, median {median:.1f} us")


if __name__ == "__main__":
    main()
