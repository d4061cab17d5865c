#!/usr/bin/env python3
"""The README's fleet picture: ``docs/images/fleet_trend.svg`` from a real ``rsrivc_fleet`` run.

    python scripts/make_fleet_figure.py [--out docs/images/fleet_trend.svg] [--workers 2]

Simulates 6 recordings of one machine a day apart (additive_rsrivc_ros.sim.fleetsim: open loop, 1 kHz, modes at 5 Hz
and 20 Hz) whose mode-2 natural frequency declines 0.5 % per recording, plus a truncated (corrupt) bag, runs
``rsrivc_fleet`` on them with ``faults.min_change.natural_frequency: 0.0175``, prints its output and saves the
trend figure of ``fleet.html``.
"""

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
from pathlib import Path

from additive_rsrivc_ros.cli import fleet
from additive_rsrivc_ros.outputs.fleet_report import trend_svg
from additive_rsrivc_ros.sim import fleetsim

REPO = Path(__file__).resolve().parents[1]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default=str(REPO / "docs" / "images" / "fleet_trend.svg"))
    p.add_argument("--workers", type=int, default=2)
    a = p.parse_args()
    with tempfile.TemporaryDirectory(prefix="rsrivc_fleet_fig_") as tmp:
        root = Path(tmp) / "machine"
        bags, params = fleetsim.write_machine_recordings(root, 6, drift_per_recording=0.005,
                                                         extra_faults={"min_change.natural_frequency": 0.0175})
        corrupt = root / "rec_corrupt"
        shutil.copytree(bags[0], corrupt)
        mcap = corrupt / "rec_00.mcap"
        mcap.write_bytes(mcap.read_bytes()[:5000])
        out = Path(tmp) / "out"
        rc = fleet.main([str(root), "--params-file", str(params), "--out", str(out), "--workers", str(a.workers),
                         "--no-report", "--no-progress"])
        if rc != 0:
            raise SystemExit(f"rsrivc_fleet exited with {rc}")
        machine = json.loads((out / "fleet_trend.json").read_text())["machines"][0]
        Path(a.out).write_text(trend_svg(machine, standalone=True), encoding="utf-8")
    print(f"wrote {a.out} ({Path(a.out).stat().st_size} bytes)")


if __name__ == "__main__":
    main()
