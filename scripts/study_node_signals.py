#!/usr/bin/env python3
"""SIGINT / SIGTERM at a random moment of rsrivc_monitor's life: start, configure, activate, numba
compilation, the offline initialization, steady estimation. A replay of the bundled 4096 Hz beam bag runs (looped)
the whole time; every trial starts the node with config/beam.yaml and a copy of a valid state file, sends SIGINT or
SIGTERM after a uniformly random delay and checks the exit: exit code, a traceback in the output, and the state
file afterwards (valid = restorable by MonitorPipeline under the same parameters; lost = missing; corrupt =
unreadable or refused; also whether the node refused it at start).

    python scripts/study_node_signals.py [--trials 50] [--max-delay 8] [--early-fraction 0.25] [--seed 0]
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PARAMS = REPO / "config" / "beam.yaml"
BAG = REPO / "bags" / "beam"
SIGNALS = ("/reference", "/plant_input", "/plant_output")


def valid_state_file(path: Path) -> str:
    """A state file of the beam configuration with an initialized estimator (6 s of simulated beam data)."""
    from additive_rsrivc_ros.config import MonitorConfig, load_params_file
    from additive_rsrivc_ros.core.monitor.pipeline import MonitorPipeline
    from additive_rsrivc_ros.sim import scenarios

    sc = scenarios.build("beam", duration_s=6.0, seed=2)
    pipe = MonitorPipeline(MonitorConfig.from_params(load_params_file(PARAMS)))
    pipe.push(sc.t, sc.r, sc.u, sc.y)
    text = json.dumps({"node": "study", "pipeline": pipe.get_state()})
    path.write_text(text)
    return "initialized" if pipe.initialized else "not initialized"


def check_state(path: Path) -> str:
    """valid / lost / corrupt (unreadable, or refused by a pipeline of the same parameters)."""
    from additive_rsrivc_ros.config import MonitorConfig, load_params_file
    from additive_rsrivc_ros.core.monitor.pipeline import MonitorPipeline, PipelineError

    if not path.exists():
        return "lost"
    try:
        MonitorPipeline(MonitorConfig.from_params(load_params_file(PARAMS)),
                        state=json.loads(path.read_text())["pipeline"])
    except (ValueError, KeyError, TypeError, PipelineError):
        return "corrupt"
    return "valid"


def trial(k: int, rng: random.Random, state0: Path, tmp: Path, env: dict, max_delay: float, early: float) -> dict:
    state = tmp / f"state_{k}.json"
    shutil.copy(state0, state)
    delay = rng.uniform(0.0, 0.5) if rng.random() < early else rng.uniform(0.0, max_delay)
    sig = rng.choice((signal.SIGINT, signal.SIGTERM))
    node = subprocess.Popen(["rsrivc_monitor", "--ros-args", "--params-file", str(PARAMS), "-p",
                             f"state_file:={state}"], env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)
    time.sleep(delay)
    node.send_signal(sig)
    t0 = time.monotonic()
    try:
        out, _ = node.communicate(timeout=90)
        rc = node.returncode
    except subprocess.TimeoutExpired:
        node.kill()
        out, _ = node.communicate()
        rc = "hang"
    phase = "configured" if "configured:" in out else "before configure"
    if "state saved" in out:
        phase = "saved"
    return {"delay": delay, "signal": signal.Signals(sig).name, "rc": rc, "traceback": "Traceback" in out,
            "state": check_state(state), "refused": " refused (" in out, "exit_s": time.monotonic() - t0,
            "lines": len([ln for ln in out.splitlines() if ln.strip()]), "phase": phase, "out": out}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--trials", type=int, default=50)
    ap.add_argument("--max-delay", type=float, default=8.0, help="signal after U(0, this) seconds (default 8)")
    ap.add_argument("--early-fraction", type=float, default=0.25, help="this fraction of the trials signals within "
                    "U(0, 0.5) s of the start (interpreter start-up, imports, rclpy.init; default 0.25)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    domain = 150 + os.getpid() % 80
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               OPENBLAS_NUM_THREADS="1", PYTHONUNBUFFERED="1")
    rng = random.Random(args.seed)
    rows = []
    with tempfile.TemporaryDirectory(prefix="study_signals_") as tmpd:
        tmp = Path(tmpd)
        state0 = tmp / "state0.json"
        print(f"state file: {valid_state_file(state0)} estimator, {check_state(state0)}")
        replay = subprocess.Popen(["rsrivc_replay", str(BAG), "--loop", "--topics", *SIGNALS,
                                   "--wait-for-subscribers", "0"], env=env, stdout=subprocess.DEVNULL,
                                  stderr=subprocess.DEVNULL)
        try:
            for k in range(args.trials):
                r = trial(k, rng, state0, tmp, env, args.max_delay, args.early_fraction)
                rows.append(r)
                print(f"trial {k + 1:3d}: {r['signal']} after {r['delay']:.2f} s ({r['phase']}) -> exit {r['rc']} "
                      f"in {r['exit_s']:.2f} s, traceback {r['traceback']}, state {r['state']}"
                      f"{', refused at start' if r['refused'] else ''}", flush=True)
                if r["traceback"] or r["state"] != "valid" or r["rc"] != 0:
                    print("    " + "\n    ".join(r["out"].strip().splitlines()[-8:]))
        finally:
            replay.send_signal(signal.SIGINT)
            try:
                replay.wait(timeout=20)
            except subprocess.TimeoutExpired:
                replay.kill()
    print()
    print(f"{'signal':8s} {'trials':>6s} {'exit 0':>6s} {'other exit':>10s} {'traceback':>9s} {'valid':>6s} "
          f"{'lost':>5s} {'corrupt':>7s} {'refused':>7s} {'max exit s':>10s}")
    for sig in ("SIGINT", "SIGTERM", "all"):
        rs = [r for r in rows if sig in ("all", r["signal"])]
        c = collections.Counter(r["state"] for r in rs)
        print(f"{sig:8s} {len(rs):6d} {sum(r['rc'] == 0 for r in rs):6d} {sum(r['rc'] != 0 for r in rs):10d} "
              f"{sum(r['traceback'] for r in rs):9d} {c['valid']:6d} {c['lost']:5d} {c['corrupt']:7d} "
              f"{sum(r['refused'] for r in rs):7d} {max((r['exit_s'] for r in rs), default=0):10.2f}")
    early = [r for r in rows if r["delay"] < 0.3]
    print(f"signals within 0.3 s of start: {len(early)}, exit 0: {sum(r['rc'] == 0 for r in early)}, "
          f"tracebacks: {sum(r['traceback'] for r in early)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
