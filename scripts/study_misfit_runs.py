#!/usr/bin/env python3
"""Longest run of misfit FRF bins of the *true* model on long windows (adequacy.MISFIT_RUN_BINS).

    python scripts/study_misfit_runs.py [--seconds 120] [--plants 40] [--rigid]

The plants, loops and excitation of ``validate_autostart.py`` (same seeds), simulated for ``--seconds`` (longer
windows get finer FRF bins, as the pipeline's regular model-order check on several memory lengths does); prints, per
plant, the FRF resolution, the compared bins, how many misfit (Bonferroni, adequacy.misfit) and the longest run of
them in a row, then the largest run. The check flags ``misfit`` from ``MISFIT_RUN_BINS`` in a row; a true model must
stay well below it. (validate_autostart.py prints the same run for the automatic starts on their 20 s windows.)
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np  # noqa: E402
import validate_autostart as va  # noqa: E402

from additive_rsrivc_ros.core.identification.adequacy import MISFIT_RUN_BINS, longest_misfit_run, misfit  # noqa: E402
from additive_rsrivc_ros.core.identification.frf import estimate_frf, model_frf_on_bins  # noqa: E402


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seconds", type=float, default=120.0)
    p.add_argument("--plants", type=int, default=40)
    p.add_argument("--rigid", action="store_true", help="every plant with a rigid body (lead loop)")
    a = p.parse_args()
    runs = []
    for i in range(a.plants):
        rng = np.random.default_rng(i)
        modes, rate, delay = va.random_plant(rng)
        if a.rigid:
            modes = va.with_rigid_body(rng, modes)
            ctrl = va.design_lead(modes, rate, delay)
        else:
            ctrl = va.design_controller(modes, rate, delay)
        f1 = min(m.natural_frequency_hz for m in modes if not m.rigid)
        t = np.arange(int(a.seconds * rate)) / rate
        r = va.square_wave(t, min(2.0, f1 / 5.0), 1.0) + va.white_noise(t.size, 0.05, rng)
        clean = va.simulate_modes(modes, rate, r=r, controller=ctrl, input_delay=delay)
        sim = va.simulate_modes(modes, rate, r=r, controller=ctrl, input_delay=delay,
                                noise=va.white_noise(t.size, 0.01 * float(np.std(clean.y)), rng), rng=rng)
        frf = estimate_frf(sim.u, sim.y, rate, sim.r)
        z, usable, thr = misfit(frf, model_frf_on_bins(frf, va._thetas(modes), [m.structure for m in modes], delay))
        run = longest_misfit_run(frf, z, usable, thr)[0]
        runs.append(run)
        print(f"plant {i:2d}  {rate:6.0f} Hz  bins {frf.resolution_hz:.3g} Hz  compared {int(usable.sum()):5d}  "
              f"misfit {int(np.sum(z > thr)):4d}  longest run {run:3d}", flush=True)
    print(f"\ntrue models on {a.seconds:g} s windows{' with a rigid body' if a.rigid else ''}: longest run of misfit "
          f"bins at most {max(runs)} over {len(runs)} plants (the check flags from {MISFIT_RUN_BINS})")


if __name__ == "__main__":
    main()
