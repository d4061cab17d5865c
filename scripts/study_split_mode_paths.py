#!/usr/bin/env python
"""Other CPUs' rounding, emulated, for the order scan's split-mode case (``test_modefind``'s
``test_a_split_mode_on_a_short_window_is_not_a_gain``): a 5 s window cut from a running square-wave loop (5 Hz
zeta 0.05 and 40 Hz), the scan's fits allowed 20 iterations, the output times ``1 + j 1e-12`` (j = 0..N-1): each a
different rounding path through the same data.

Per path: the modes the scan finds with its protections (must be the true 2 on every path), with the margin alone
(the paired test off: also the true 2), and with both protections off (the free response of the record in motion
not projected out of the refits, and no paired test): the negative control, which picks a split 5 Hz mode on some
paths (K = 3 or 4) and not on others, depending on where a non-converging K = 3 fit stops.

Usage: ``python scripts/study_split_mode_paths.py [--paths 13]``
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "test"))
from frf_cases import CONTROLLER, DELAY, FS, MODES, split_mode_window  # noqa: E402

from additive_rsrivc_ros.core.identification import modefind  # noqa: E402
from additive_rsrivc_ros.core.identification.offline import stable  # noqa: E402


def _right(res) -> bool:
    """The test's check: the true number of modes, each frequency within 1 %, damping within 15 %."""
    return res.K == len(MODES) and all(
        abs(m[0] / t.natural_frequency_hz - 1.0) < 0.01 and abs(m[1] / t.damping_ratio - 1.0) < 0.15
        for m, t in zip(res.modal, MODES, strict=True)) and all(res.identifiable)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--paths", type=int, default=13, help="rounding paths (output x (1 + j 1e-12))")
    args = ap.parse_args(argv)
    modefind.SCAN_MAX_ITERATIONS = 20
    gain_t = modefind.GAIN_T

    def search(path: int):
        r, u, y = split_mode_window(path)
        return modefind.find_modes(u, y, FS, r=r, controller=CONTROLLER, input_delay=DELAY,
                                   refit_tol=modefind.SCAN_TOL)

    print("path  protected       margin alone    both off (negative control)")
    bad = 0
    for j in range(args.paths):
        a = search(j)
        modefind.GAIN_T = -np.inf
        b = search(j)
        stable.FREE_RESPONSE_REFIT = False
        c = search(j)
        stable.FREE_RESPONSE_REFIT, modefind.GAIN_T = True, gain_t
        bad += not (_right(a) and _right(b))
        print(f"{j:4d}  K={a.K} {'right' if _right(a) else 'WRONG':5s}   K={b.K} {'right' if _right(b) else 'WRONG':5s}"
              f"   K={c.K} {'(split)' if c.K > len(MODES) else ''}")
    print(f"{bad} of {args.paths} paths wrong with the protections (must be 0)")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
