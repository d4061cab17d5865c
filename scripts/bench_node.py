#!/usr/bin/env python3
"""Benchmark of rsrivc_monitor over DDS (issue 6): the 4096 Hz beam replayed for 60 s with K = 2.

Prints: messages published / received per topic, samples lost and misaligned, node CPU (from
/proc/<pid>/stat, in cores), the median / p95 delay from a sample's arrival to the estimate that includes
it (measured inside the node: arrival of the sample's last message -> return of the pipeline push that
updated the estimator with it), the estimator's real-time factor, the final estimate vs the truth, and, with
``--speedups``, the highest loop rate sustained without loss (the bag replayed faster than recorded).

    python scripts/bench_node.py [--duration 60] [--speedups 2 4 8] [--speedup-duration 10]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
PARAMS = REPO / "config" / "beam.yaml"
NODE = "additive_rsrivc_monitor"
SIGNALS = ("/reference", "/plant_input", "/plant_output")


def proc_cpu_s(pid: int) -> float:
    """utime + stime of a process in seconds (/proc/<pid>/stat fields 14, 15)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


class Listener:
    """Subscribes to /diagnostics and ~/modes in its own context."""

    def __init__(self, domain: int) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from std_msgs.msg import Float64MultiArray

        self.rclpy = rclpy
        self.ctx = Context()
        rclpy.init(context=self.ctx, domain_id=domain)
        self.node = rclpy.create_node("bench_listener", context=self.ctx)
        self.est: dict[str, str] = {}
        self.modes: np.ndarray | None = None
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._diag, 50)
        self.node.create_subscription(Float64MultiArray, f"/{NODE}/modes", self._modes, 50)
        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.ex.add_node(self.node)
        self.th = threading.Thread(target=self._spin, daemon=True)
        self.th.start()

    def _spin(self) -> None:
        try:
            while self.ctx.ok():
                self.ex.spin_once(timeout_sec=0.1)
        except Exception:  # noqa: BLE001 - context shut down
            pass

    def _diag(self, msg) -> None:
        for st in msg.status:
            if st.name == f"{NODE}: estimator":
                self.est = {kv.key: kv.value for kv in st.values}
                self.est["_level"] = str(st.level[0] if isinstance(st.level, bytes) else st.level)

    def _modes(self, msg) -> None:
        self.modes = np.asarray(msg.data).reshape(-1, 6)

    def close(self) -> None:
        self.rclpy.try_shutdown(context=self.ctx)
        self.th.join(timeout=5)


def run_once(bag: Path, speed: float, domain: int, env: dict) -> dict:
    """Start a fresh node, replay ``bag`` at ``speed``, return the node's figures."""
    node = subprocess.Popen(["rsrivc_monitor", "--ros-args", "--params-file", str(PARAMS)], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lis = Listener(domain)
    try:
        t_wait = time.monotonic()
        while not lis.est and time.monotonic() - t_wait < 60:
            time.sleep(0.1)
        cpu0, w0 = proc_cpu_s(node.pid), time.monotonic()
        rep = subprocess.run(["rsrivc_replay", str(bag), "--rate", str(speed), "--topics", *SIGNALS,
                              "--wait-for-subscribers", "60", "--stats"], env=env, capture_output=True, text=True)
        cpu_r, w_r = proc_cpu_s(node.pid), time.monotonic()
        if rep.returncode != 0:
            raise RuntimeError(f"rsrivc_replay failed: {rep.stderr.strip()}")
        # let the node drain its queues and publish a final status
        time.sleep(2.0)
        cpu1, w1 = proc_cpu_s(node.pid), time.monotonic()
        est = dict(lis.est)
        modes = None if lis.modes is None else lis.modes.copy()
        alive = node.poll() is None
    finally:
        lis.close()
        node.terminate()
        out, _ = node.communicate(timeout=30)
        if os.environ.get("BENCH_NODE_LOG"):
            print(out)
    return {"est": est, "modes": modes, "cpu_cores": (cpu1 - cpu0) / (w1 - w0), "wall_s": w1 - w0,
            "cpu_replay": (cpu_r - cpu0) / (w_r - w0), "wall_replay_s": w_r - w0,
            "replay": rep.stdout.strip() + rep.stderr.strip(), "alive": alive, "rc": node.returncode, "log": out}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration", type=float, default=60.0, help="seconds of beam data (default 60)")
    ap.add_argument("--speedups", type=float, nargs="*", default=[], help="replay speed factors to try for the "
                    "highest loss-free loop rate, e.g. 2 4 8")
    ap.add_argument("--speedup-duration", type=float, default=10.0, help="seconds of bag per speed-up run")
    args = ap.parse_args()
    domain = 150 + os.getpid() % 80
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               OPENBLAS_NUM_THREADS="1", PYTHONUNBUFFERED="1")
    from additive_rsrivc_ros.core import scenarios

    with tempfile.TemporaryDirectory(prefix="bench_node_") as tmp:
        t0 = time.monotonic()
        sc = scenarios.build("beam", duration_s=args.duration, seed=0)
        bag = sc.write_bag(Path(tmp) / "beam")
        n = sc.t.size
        print(f"beam bag: {args.duration:g} s at {sc.rate_hz:g} Hz, {n} samples per topic "
              f"(simulated in {time.monotonic() - t0:.1f} s)")
        r = run_once(bag, 1.0, domain, env)
        e = r["est"]
        recv = int(e.get("samples_received", 0))
        aligned = int(e.get("samples_aligned", 0))
        print(f"replay: {r['replay']}")
        print(f"node alive after replay: {r['alive']}, exit code after SIGTERM: {r['rc']}")
        print(f"messages published: {3 * n}, received by the node: {recv}, lost: {3 * n - recv}")
        print(f"samples aligned: {aligned} of {n}; misaligned events: {e.get('misaligned_events')}, dropped: "
              f"{e.get('samples_dropped')}, input pauses: {e.get('input_pauses')}, gaps: {e.get('gaps')}, "
              f"rate mismatches: {e.get('rate_mismatches')}")
        print(f"node CPU: {r['cpu_replay']:.3f} cores during the replay ({r['wall_replay_s']:.1f} s), "
              f"{r['cpu_cores']:.3f} cores including 2 s of draining")
        print(f"delay arrival -> estimate: median {float(e.get('delay_median_ms', 'nan')):.2f} ms, p95 "
              f"{float(e.get('delay_p95_ms', 'nan')):.2f} ms, max {float(e.get('delay_max_ms', 'nan')):.2f} ms")
        print(f"estimator real-time factor: {float(e.get('real_time_factor', 'nan')):.1f}, phase {e.get('phase')}, "
              f"health: {e.get('reasons') or 'ok'}")
        if r["modes"] is not None:
            truth = sc.truth[:, -1, :]
            for i in range(sc.n_estimated):
                m = r["modes"][i]
                print(f"mode {i + 1}: f {m[0]:.4f} Hz (truth {truth[i, 0]:.4f}, std {m[3]:.2g}), zeta {m[1]:.4f} "
                      f"(truth {truth[i, 1]:.4f}), gain {m[2]:.4g} (truth {truth[i, 2]:.4g})")
        best = sc.rate_hz if recv == 3 * n and aligned == n else 0.0
        for s in args.speedups:
            m = int(args.speedup_duration * sc.rate_hz)
            short = scenarios.build("beam", duration_s=args.speedup_duration, seed=1)
            bag_s = short.write_bag(Path(tmp) / f"beam_short_{s:g}")
            rs = run_once(bag_s, s, domain, env)
            es = rs["est"]
            recv_s, al_s = int(es.get("samples_received", 0)), int(es.get("samples_aligned", 0))
            ok = recv_s == 3 * m and al_s == m and int(es.get("misaligned_events", 1)) == 0
            print(f"x{s:g} ({s * sc.rate_hz:.0f} Hz): received {recv_s}/{3 * m}, aligned {al_s}/{m}, "
                  f"node CPU {rs['cpu_cores']:.2f} cores, median delay {float(es.get('delay_median_ms', 'nan')):.2f} "
                  f"ms -> {'no loss' if ok else 'LOSS'}")
            if ok:
                best = max(best, s * sc.rate_hz)
        print(f"highest loop rate sustained without loss: {best:.0f} Hz (of the rates tried)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
