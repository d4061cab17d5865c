#!/usr/bin/env python3
"""Digest of what ``rsrivc_diagnose`` writes for a fixed set of records, to prove a refactor changes nothing.

Usage: ``python scripts/check_outputs_identical.py --save before.json`` on the old code, then
``python scripts/check_outputs_identical.py --compare before.json`` on the new code. Each case is a bundled bag
or a simulated record (fixed seed) diagnosed with a shipped params file, with mode guesses and with the
automatic start; the digest covers estimates.csv, events.csv and summary.json without its wall-clock timings and
paths. Exit status 1 when any digest differs.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# (name, bag or (scenario, duration s, seed, extra --set), params file)
CASES: list[tuple[str, str | tuple[str, float, int, list[str]], str]] = [
    ("beam", "bags/beam", "config/beam.yaml"),
    ("beam_fault", "bags/beam_fault", "config/beam_fault.yaml"),
    ("beam_fault_auto", "bags/beam_fault", "config/beam_plant.yaml"),
    ("paper_example", ("paper_example", 400.0, 3, []), "config/paper_example.yaml"),
    ("sensor_fault", ("sensor_fault", 500.0, 4, ["fault_time_s=100.0"]), "config/sensor_fault.yaml"),
    ("rigid_body", ("rigid_body", 60.0, 5, []), "config/rigid_body.yaml"),
    ("open_loop", ("open_loop_multisine", 60.0, 6, []), "config/open_loop_multisine.yaml"),
    ("beam_sim_fault", ("beam_fault", 40.0, 7, ["fault_time_s=22.0"]), "config/beam_fault.yaml"),
]
VOLATILE = {"timings_s", "seconds", "realtime_factor", "bag", "params_file", "files", "bag_metadata"}


def _without_clock(value: object) -> object:
    """The summary without wall-clock timings and paths (they differ between runs of the same code)."""
    if isinstance(value, dict):
        return {k: _without_clock(v) for k, v in value.items() if k not in VOLATILE}
    if isinstance(value, list):
        return [_without_clock(v) for v in value]
    return value


def _digest(out: Path) -> dict[str, str]:
    result = {}
    for name in ("estimates.csv", "events.csv"):
        result[name] = hashlib.sha256((out / name).read_bytes()).hexdigest()
    summary = _without_clock(json.loads((out / "summary.json").read_text()))
    result["summary.json"] = hashlib.sha256(json.dumps(summary, sort_keys=True).encode()).hexdigest()
    return result


def _run_case(tmp: Path, name: str, source: str | tuple[str, float, int, list[str]], params: str) -> dict[str, str]:
    if isinstance(source, tuple):
        scenario, duration, seed, sets = source
        bag = tmp / f"{name}_bag"
        cmd = ["rsrivc_simulate", "--scenario", scenario, "--duration", str(duration), "--seed", str(seed),
               "--out", str(bag)]
        for item in sets:
            cmd += ["--set", item]
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, cwd=ROOT)
    else:
        bag = ROOT / source
    out = tmp / f"{name}_out"
    subprocess.run(["rsrivc_diagnose", str(bag), "--params-file", params, "--out", str(out), "--no-report",
                    "--quiet"], check=True, stdout=subprocess.DEVNULL, cwd=ROOT)
    return _digest(out)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    group = parser.add_mutually_exclusive_group(required=True)
    group.add_argument("--save", type=Path, help="write the digests to this JSON file")
    group.add_argument("--compare", type=Path, help="compare with the digests in this JSON file")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        digests = {name: _run_case(Path(tmp), name, source, params) for name, source, params in CASES}
    if args.save:
        args.save.write_text(json.dumps(digests, indent=1, sort_keys=True))
        print(f"{len(digests)} cases saved to {args.save}")
        return 0
    before = json.loads(args.compare.read_text())
    differ = [f"{case}/{name}" for case, files in digests.items() for name, digest in files.items()
              if before.get(case, {}).get(name) != digest]
    print(f"{len(digests) - len({d.split('/')[0] for d in differ})} of {len(digests)} cases identical"
          + (f"; differ: {', '.join(differ)}" if differ else ""))
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
