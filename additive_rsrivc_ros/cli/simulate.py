"""``rsrivc_simulate``: write a simulated rosbag2 with known truth (docs/INTERFACE.md).

    rsrivc_simulate --scenario beam_fault --out /tmp/beam_fault [--duration 30] [--seed 0] [--storage mcap]
    rsrivc_simulate --list
    rsrivc_simulate --scenario beam --out b --set manipulation_start_s=5 --set manipulation_end_s=20

The bag is written into a temporary directory next to ``--out`` and renamed at the end: an error never leaves a
half-written bag behind. Bad input: one line on stderr, exit status 2 (usage) or 1 (failure).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import sys
from pathlib import Path
from typing import Any

from ..process_exit import console_entry
from .parser import OneLineParser


def _parser() -> argparse.ArgumentParser:
    p = OneLineParser(prog="rsrivc_simulate", description="Write a simulated rosbag2 with known truth.")
    p.add_argument("--scenario", help="scenario name (see --list)")
    p.add_argument("--out", help="bag directory to create (must not exist)")
    p.add_argument("--duration", type=float, default=None, help="duration in s (default: the scenario's)")
    p.add_argument("--seed", type=int, default=0, help="random seed (non-negative integer)")
    p.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap", help="storage plugin")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scenario parameter (JSON value), repeatable")
    p.add_argument("--truth-rate", type=float, default=10.0, help="rate of /truth/modes in Hz")
    p.add_argument("--list", action="store_true", help="list the scenarios and their parameters, then exit")
    return p


def _overrides(items: list[str]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise ValueError(f"--set expects KEY=VALUE, got {item!r}")
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    return out


@console_entry
def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    from ..sim.scenarios import SCENARIOS, build, list_scenarios

    if args.list:
        for name in list_scenarios():
            sc = SCENARIOS[name]
            print(f"{name:22s} {sc.default_duration_s:8.1f} s  {sc.description}")
            print(f"{'':22s} parameters: {json.dumps(sc.parameters, sort_keys=True)}")
        return 0
    if not args.scenario or not args.out:
        print("rsrivc_simulate: error: --scenario and --out are required (or --list)", file=sys.stderr)
        return 2
    if args.scenario not in SCENARIOS:
        print(f"rsrivc_simulate: error: unknown scenario {args.scenario!r} (known: {', '.join(list_scenarios())})",
              file=sys.stderr)
        return 2
    if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0):
        print(f"rsrivc_simulate: error: --duration must be a positive number of seconds, got {args.duration}",
              file=sys.stderr)
        return 2
    if args.seed < 0:
        print(f"rsrivc_simulate: error: --seed must be non-negative, got {args.seed}", file=sys.stderr)
        return 2
    if not (math.isfinite(args.truth_rate) and args.truth_rate > 0):
        print(f"rsrivc_simulate: error: --truth-rate must be > 0, got {args.truth_rate}", file=sys.stderr)
        return 2
    out = Path(args.out)
    if out.exists() or out.is_symlink():
        print(f"rsrivc_simulate: error: {out} exists already (not overwriting)", file=sys.stderr)
        return 1
    parent = out.absolute().parent
    if not parent.is_dir():
        print(f"rsrivc_simulate: error: cannot write {out}: directory {parent} does not exist", file=sys.stderr)
        return 1
    if not os.access(parent, os.W_OK | os.X_OK):
        print(f"rsrivc_simulate: error: directory {parent} is not writable", file=sys.stderr)
        return 1
    tmp = parent / f".{out.name}.partial-{os.getpid()}"
    try:
        data = build(args.scenario, duration_s=args.duration, seed=args.seed, **_overrides(args.set))
        tmp.mkdir()
        # the bag keeps its final name inside the temporary directory: file names in metadata.yaml stay right
        data.write_bag(tmp / out.name, storage=args.storage, truth_rate_hz=args.truth_rate)
        os.rename(tmp / out.name, out)
    except (ValueError, OSError) as exc:
        msg = str(exc).strip().splitlines()
        print(f"rsrivc_simulate: error: {msg[0] if msg else type(exc).__name__}", file=sys.stderr)
        return 1
    except Exception as exc:  # noqa: BLE001 - e.g. rosbags WriterError: still one line, no traceback
        msg = str(exc).strip().splitlines()
        print(f"rsrivc_simulate: error: {type(exc).__name__}: {msg[0] if msg else ''}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("rsrivc_simulate: interrupted", file=sys.stderr)
        return 130
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    n = data.t.size
    print(f"wrote {out} ({args.storage}): scenario {args.scenario}, seed {args.seed}, {n} samples at "
          f"{data.rate_hz:g} Hz ({n / data.rate_hz:g} s), params {data.config_path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
