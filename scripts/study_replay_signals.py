#!/usr/bin/env python3
"""SIGTERM / SIGINT at a random moment of a looping ``rsrivc_replay`` (the signal-handler deadlock of
additive_rsrivc_ros.signal_stop). Each trial plays a 0.5 s, 1 kHz, three-topic bag with ``--loop``, sends the
signal after a uniformly random 1-3 s and waits up to 15 s for the exit. A hang is aborted with SIGABRT so that
``-X faulthandler`` prints every thread's stack. Prints one row per outcome and the stop latency.

Before the fix (``threading.Event.set`` in the handler) about 1 trial in 20 hung.

    python scripts/study_replay_signals.py [--trials 120] [--seed 0]
"""

from __future__ import annotations

import argparse
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from additive_rsrivc_ros.io.bagio import write_bag

REPO = Path(__file__).resolve().parents[1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=120)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    rng = random.Random(args.seed)
    outcomes: dict[str, int] = {"clean": 0, "hang": 0, "bad exit": 0}
    latency: list[float] = []
    with tempfile.TemporaryDirectory() as tmp:
        bag = Path(tmp) / "bag"
        k = np.arange(500.0)                                  # 0.5 s at 1 kHz on /reference, /plant_input, ...
        write_bag(bag, 1000.0, 10 * k + 1, 10 * k + 2, 10 * k)
        env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", PYTHONUNBUFFERED="1")
        for i in range(args.trials):
            env["ROS_DOMAIN_ID"] = str(101 + (os.getpid() + i) % 100)
            sig = rng.choice((signal.SIGTERM, signal.SIGINT))
            proc = subprocess.Popen([sys.executable, "-X", "faulthandler", "-m", "additive_rsrivc_ros.cli.replay",
                                     str(bag), "--loop"], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                    text=True, cwd=REPO)
            time.sleep(rng.uniform(1.0, 3.0))
            proc.send_signal(sig)
            t0 = time.monotonic()
            try:
                _, err = proc.communicate(timeout=15)
            except subprocess.TimeoutExpired:
                outcomes["hang"] += 1
                proc.send_signal(signal.SIGABRT)
                _, err = proc.communicate()
                print(f"trial {i}: HANG after {sig.name}; stacks:\n{err[-4000:]}", flush=True)
                continue
            latency.append(time.monotonic() - t0)
            if proc.returncode == 0 and "stopped after" in err and "Traceback" not in err:
                outcomes["clean"] += 1
            else:
                outcomes["bad exit"] += 1
                print(f"trial {i}: exit {proc.returncode} after {sig.name}: {err[-1500:]}", flush=True)
    print(f"{args.trials} trials (SIGTERM or SIGINT after 1-3 s of a looping replay)")
    for k, v in outcomes.items():
        print(f"  {k:9s} {v}")
    if latency:
        latency.sort()
        print(f"  stop latency: median {latency[len(latency) // 2]:.3f} s, max {latency[-1]:.3f} s")
    return 0 if outcomes["hang"] == outcomes["bad exit"] == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
