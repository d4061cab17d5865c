#!/usr/bin/env python3
"""Benchmark of rsrivc_monitor over DDS: the 4096 Hz beam replayed for 60 s with K = 2.

Prints: messages published / received per topic, samples lost and misaligned, node CPU (from
/proc/<pid>/stat, in cores), the median / p95 delay from a sample's arrival to the estimate that includes
it (measured inside the node: arrival of the sample's last message -> return of the pipeline push that
updated the estimator with it), the estimator's real-time factor, the final estimate vs the truth, and, with
``--speedups``, the highest loop rate sustained without loss (the bag replayed faster than recorded).

Options: ``--hog N`` runs N busy-loop subprocesses beside the node (CPU contention) and says whether the
node reported every loss (never misaligned or lost in silence); ``--publish-rate HZ`` sets publish_rate_hz (does
publishing keep up with 4096 Hz x 3 inputs?); ``--rss-absent SECONDS`` instead replays only /plant_input and
/plant_output (looped; /reference absent) and prints the node's RSS every ``--rss-every`` seconds with the growth
rate extrapolated to one hour.

``--block N`` (default 100; 0 skips it) then replays the same bag as block input (``rsrivc_replay
--block N``, node ``block.topic``) into a fresh node and prints its samples lost, gaps and node CPU next to the
per-sample Float64 figure of the same run. Node CPU is process CPU time over wall time while the bag plays (from
/proc, sampled every 0.1 s; the replay's own start-up, reading the bag, is left out).

    python scripts/bench_node.py [--duration 60] [--block 100] [--speedups 2 4 8] [--speedup-duration 10]
                                 [--hog 2] [--publish-rate 1000] [--rss-absent 180 --rss-every 10]
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

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


def start_hogs(n: int) -> list[subprocess.Popen]:
    """``n`` busy-loop subprocesses (one core each when free)."""
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]


def stop_hogs(hogs: list[subprocess.Popen]) -> None:
    for h in hogs:
        h.kill()
        h.wait()


def rss_mb(pid: int) -> float:
    """Resident set size of a process in MB (/proc/<pid>/status VmRSS)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


class CpuSampler:
    """(monotonic, CPU seconds) of a process every ``period`` s in a thread; CPU cores over any window."""

    def __init__(self, pid: int, period: float = 0.1) -> None:
        self.pid, self.period = pid, period
        self.pts: list[tuple[float, float]] = []
        self.stop = threading.Event()
        self.th = threading.Thread(target=self._run, daemon=True)
        self.th.start()

    def _run(self) -> None:
        while not self.stop.is_set():
            try:
                self.pts.append((time.monotonic(), proc_cpu_s(self.pid)))
            except OSError:
                return
            self.stop.wait(self.period)

    def close(self) -> None:
        self.stop.set()
        self.th.join(2.0)

    def cores(self, t0: float, t1: float) -> float:
        """CPU cores used between ``t0`` and ``t1`` (linear interpolation of the samples)."""
        if len(self.pts) < 2 or not t1 > t0:
            return float("nan")
        ts, cs = np.array(self.pts).T
        return float((np.interp(t1, ts, cs) - np.interp(t0, ts, cs)) / (t1 - t0))


def play_window(replay_stdout: str, t_end: float) -> tuple[float, float]:
    """Wall-clock window of the playback itself: ``rsrivc_replay --stats`` prints its duration; it ended at most a
    moment before the process exited at ``t_end``."""
    m = re.search(r"published \d+ messages in ([0-9.]+) s", replay_stdout)
    return (t_end - float(m.group(1)), t_end) if m else (float("nan"), t_end)


def node_cmd(extra: list[str]) -> list[str]:
    cmd = ["rsrivc_monitor", "--ros-args", "--params-file", str(PARAMS)]
    for p in extra:
        cmd += ["-p", p]
    return cmd


def run_once(bag: Path, speed: float, domain: int, env: dict, extra: list[str] | None = None,
             hogs: int = 0, block: int = 0) -> dict:
    """Start a fresh node, replay ``bag`` at ``speed`` (with ``hogs`` busy loops beside; ``block``: as blocks of that
    many rows into the node's block input), return the figures."""
    extra = [*(extra or []), *(["block.topic:=/block"] if block else [])]
    node = subprocess.Popen(node_cmd(extra), env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lis = Listener(domain)
    sampler = CpuSampler(node.pid)
    hog = []
    signals = ["--block", str(block)] if block else ["--topics", *SIGNALS]
    try:
        t_wait = time.monotonic()
        while not lis.est and time.monotonic() - t_wait < 60:
            time.sleep(0.1)
        hog = start_hogs(hogs)
        cpu0, w0 = proc_cpu_s(node.pid), time.monotonic()
        rep = subprocess.run(["rsrivc_replay", str(bag), "--rate", str(speed), *signals,
                              "--wait-for-subscribers", "60", "--stats"], env=env, capture_output=True, text=True)
        cpu_r, w_r = proc_cpu_s(node.pid), time.monotonic()
        stop_hogs(hog)
        hog = []
        if rep.returncode != 0:
            raise RuntimeError(f"rsrivc_replay failed: {rep.stderr.strip()}")
        # let the node drain its queues and publish a final status
        time.sleep(2.0)
        cpu1, w1 = proc_cpu_s(node.pid), time.monotonic()
        est = dict(lis.est)
        modes = None if lis.modes is None else lis.modes.copy()
        alive = node.poll() is None
    finally:
        stop_hogs(hog)
        lis.close()
        sampler.close()
        node.terminate()
        out, _ = node.communicate(timeout=30)
        if os.environ.get("BENCH_NODE_LOG"):
            print(out)
    p0, p1 = play_window(rep.stdout, w_r)
    return {"est": est, "modes": modes, "cpu_cores": (cpu1 - cpu0) / (w1 - w0), "wall_s": w1 - w0,
            "cpu_play": sampler.cores(p0, p1), "wall_play_s": p1 - p0, "cpu_late": sampler.cores(0.5 * (p0 + p1), p1),
            "cpu_replay": (cpu_r - cpu0) / (w_r - w0), "wall_replay_s": w_r - w0,
            "replay": rep.stdout.strip() + rep.stderr.strip(), "alive": alive, "rc": node.returncode, "log": out}


def loss_verdict(e: dict, published: int, n: int) -> str:
    """Did the node keep up, or report what it lost? (Float64 carries no sequence numbers: a message lost before
    the node's queue shows as a count mismatch, a pause or a dropped count, never as nothing.)"""
    recv = int(e.get("samples_received", 0))
    aligned = int(e.get("samples_aligned", 0))
    counted = {k: int(float(e.get(k, 0) or 0)) for k in ("samples_dropped", "misaligned_events", "input_pauses",
                                                        "node_stall_gaps", "queue_dropped", "gaps")}
    if recv == published and aligned == n:
        return "verdict: kept up (every message received and aligned)"
    said = {k: v for k, v in counted.items() if v}
    if said:
        return (f"verdict: did not keep up ({published - recv} messages not received, {n - aligned} samples not "
                f"aligned) and reported it: " + ", ".join(f"{k} {v}" for k, v in said.items()))
    return (f"verdict: LOST IN SILENCE ({published - recv} messages not received, {n - aligned} samples not "
            "aligned, no counter moved)")


def rss_absent(bag: Path, domain: int, env: dict, extra: list[str], seconds: float, every: float) -> int:
    """RSS of the node while /reference is absent and the other two topics stream (looped replay)."""
    node = subprocess.Popen(node_cmd(extra), env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lis = Listener(domain)
    rep = None
    pts: list[tuple[float, float]] = []
    try:
        rep = subprocess.Popen(["rsrivc_replay", str(bag), "--loop", "--topics", *SIGNALS[1:],
                                "--wait-for-subscribers", "60"], env=env, stdout=subprocess.DEVNULL,
                               stderr=subprocess.DEVNULL)
        t0 = time.monotonic()
        while time.monotonic() - t0 < seconds:
            time.sleep(every)
            t, m = time.monotonic() - t0, rss_mb(node.pid)
            pts.append((t, m))
            e = lis.est
            print(f"t {t:6.0f} s  RSS {m:7.1f} MB  received {e.get('samples_received')}  queue backlog "
                  f"{e.get('queue_backlog')}  queue drops {e.get('queue_dropped_per_topic')}", flush=True)
    finally:
        if rep is not None:
            rep.send_signal(2)
            rep.wait(timeout=20)
        lis.close()
        node.terminate()
        out, _ = node.communicate(timeout=30)
    late = [(t, m) for t, m in pts if t >= min(60.0, seconds / 2)]
    if len(late) >= 2:
        slope = np.polyfit([t for t, _ in late], [m for _, m in late], 1)[0]
        print(f"RSS growth after {late[0][0]:.0f} s: {slope * 60:.3f} MB/min (least squares), extrapolated to 60 min: "
              f"{late[-1][1] + slope * (3600 - late[-1][0]):.1f} MB (last {late[-1][1]:.1f} MB)")
    print("node log lines about the absent topic / queues:")
    for ln in out.splitlines():
        if "queue of" in ln or "no data on" in ln:
            print("  " + ln.strip()[:200])
    return 0


def report_block(bag: Path, n: int, domain: int, env: dict, extra: list[str], args: Any, per_sample: dict) -> None:
    """Block input: the same bag as blocks of ``args.block`` rows into a fresh node."""
    b = run_once(bag, 1.0, domain, env, extra, args.hog, block=args.block)
    e = b["est"]
    aligned = int(e.get("samples_aligned", 0))
    n_blocks = -(-n // args.block)
    print(f"block input, {args.block} rows per message ({n_blocks} messages): node received "
          f"{e.get('samples_received')} samples in {e.get('block_messages')} messages, samples lost {n - aligned} of "
          f"{n}; index gaps {e.get('block_gaps')} ({e.get('block_missing_samples')} samples), duplicates "
          f"{e.get('block_duplicate_samples')}, malformed {e.get('malformed_messages')}, queue drops "
          f"{e.get('queue_dropped')}, pipeline gaps {e.get('gaps')}; invariant relative residual "
          f"{e.get('block_invariant_relative_residual')}; phase {e.get('phase')}; node alive {b['alive']}, exit "
          f"{b['rc']}")
    print(f"node CPU while the bag played: block input {b['cpu_play']:.3f} cores ({b['wall_play_s']:.1f} s), "
          f"per-sample Float64 x 3 topics {per_sample['cpu_play']:.3f} cores ({per_sample['wall_play_s']:.1f} s), "
          f"same bag, same run; second half of the playback (after the offline initialization): block "
          f"{b['cpu_late']:.3f}, per-sample {per_sample['cpu_late']:.3f} cores; load average "
          f"{os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs")
    if b["modes"] is not None and per_sample["modes"] is not None:
        d = np.abs(b["modes"][:, :3] - per_sample["modes"][:, :3]) / np.abs(per_sample["modes"][:, :3])
        print(f"last ~/modes, block vs per-sample input: max relative difference {np.max(d):.2g} (the last reports "
              "of the two runs need not fall on the same sample)")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration", type=float, default=60.0, help="seconds of beam data (default 60)")
    ap.add_argument("--speedups", type=float, nargs="*", default=[], help="replay speed factors to try for the "
                    "highest loss-free loop rate, e.g. 2 4 8")
    ap.add_argument("--speedup-duration", type=float, default=10.0, help="seconds of bag per speed-up run")
    ap.add_argument("--hog", type=int, default=0, help="busy-loop subprocesses running beside the node")
    ap.add_argument("--block", type=int, default=100, help="rows per block message of the block-input run ("
                    "default 100; 0: no block run)")
    ap.add_argument("--publish-rate", type=float, default=0.0, help="publish_rate_hz of the node (default: the "
                    "params file's)")
    ap.add_argument("--rss-absent", type=float, default=0.0, help="instead: seconds of RSS measurement with "
                    "/reference absent")
    ap.add_argument("--rss-every", type=float, default=10.0, help="RSS print interval in s (default 10)")
    args = ap.parse_args()
    domain = 150 + os.getpid() % 80
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               OPENBLAS_NUM_THREADS="1", PYTHONUNBUFFERED="1")
    from additive_rsrivc_ros.sim import scenarios

    with tempfile.TemporaryDirectory(prefix="bench_node_") as tmp:
        t0 = time.monotonic()
        sc = scenarios.build("beam", duration_s=args.duration, seed=0)
        bag = sc.write_bag(Path(tmp) / "beam")
        n = sc.t.size
        print(f"beam bag: {args.duration:g} s at {sc.rate_hz:g} Hz, {n} samples per topic "
              f"(simulated in {time.monotonic() - t0:.1f} s)")
        extra = [f"publish_rate_hz:={args.publish_rate}"] if args.publish_rate else []
        if args.rss_absent:
            return rss_absent(bag, domain, env, extra, args.rss_absent, args.rss_every)
        r = run_once(bag, 1.0, domain, env, extra, args.hog)
        if args.hog or args.publish_rate:
            print(f"conditions: {args.hog} busy-loop subprocess(es) beside the node, publish_rate_hz "
                  f"{args.publish_rate or 'from beam.yaml'}; load average {os.getloadavg()[0]:.2f}")
        e = r["est"]
        recv = int(e.get("samples_received", 0))
        aligned = int(e.get("samples_aligned", 0))
        print(f"replay: {r['replay']}")
        print(f"node alive after replay: {r['alive']}, exit code after SIGTERM: {r['rc']}")
        print(f"messages published: {3 * n}, received by the node: {recv}, lost: {3 * n - recv}")
        print(f"samples aligned: {aligned} of {n}; misaligned events: {e.get('misaligned_events')}, dropped: "
              f"{e.get('samples_dropped')}, input pauses: {e.get('input_pauses')}, gaps: {e.get('gaps')}, "
              f"rate mismatches: {e.get('rate_mismatches')}")
        print(f"node CPU: {r['cpu_play']:.3f} cores while the bag played ({r['wall_play_s']:.1f} s); "
              f"{r['cpu_replay']:.3f} cores over the whole replay process ({r['wall_replay_s']:.1f} s), "
              f"{r['cpu_cores']:.3f} cores including 2 s of draining")
        print(f"delay arrival -> estimate: median {float(e.get('delay_median_ms', 'nan')):.2f} ms, p95 "
              f"{float(e.get('delay_p95_ms', 'nan')):.2f} ms, max {float(e.get('delay_max_ms', 'nan')):.2f} ms")
        print(f"estimator real-time factor: {float(e.get('real_time_factor', 'nan')):.1f}, phase {e.get('phase')}, "
              f"health: {e.get('reasons') or 'ok'}")
        print(f"node's own timing: executor stalls {e.get('node_stalls')} (max {e.get('node_stall_max_s')} s), "
              f"worker stalls {e.get('worker_stalls')} (max {e.get('worker_stall_max_s')} s), time gaps from node "
              f"stalls {e.get('node_stall_gaps')}, queue drops {e.get('queue_dropped_per_topic')}, reports "
              f"coalesced {e.get('reports_coalesced')}, arrival rates {e.get('arrival_rate_hz')}")
        print(loss_verdict(e, 3 * n, n))
        if r["modes"] is not None:
            truth = sc.truth[:, -1, :]
            for i in range(sc.n_estimated):
                m = r["modes"][i]
                print(f"mode {i + 1}: f {m[0]:.4f} Hz (truth {truth[i, 0]:.4f}, std {m[3]:.2g}), zeta {m[1]:.4f} "
                      f"(truth {truth[i, 1]:.4f}), gain {m[2]:.4g} (truth {truth[i, 2]:.4g})")
        if args.block:
            report_block(bag, n, domain, env, extra, args, r)
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
