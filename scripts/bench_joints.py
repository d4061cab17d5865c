#!/usr/bin/env python3
"""Benchmark of many axes in one process (``rsrivc_joints``) over DDS: per-joint and total CPU, samples lost, delay.

Cases (``--cases``, default all three):

* ``joints1k``: N joints (``--joints``, default 7) of the simulated arm (sim/arm.py), published as a robot does: every
  joint in one ``sensor_msgs/JointState`` per sample on ``/joint_commands`` (position = reference) and
  ``/joint_states`` (position = output, effort = input), 1 kHz, ``--duration`` s; the memories are 4 s and 2 s
  (config/joints/arm.yaml: 20 s and 5 s) so that every joint is monitoring (fault tests running) from 42 s on.
* ``joints4k``: the same at 4 kHz (the arm's controller re-derived for the rate).
* ``blocks``: M block-input axes (``--axes``, default 8), each the 4096 Hz beam (config/beam.yaml) on its own block
  topic ``/axisK/block`` (rows of ``--block`` samples), all in one ``rsrivc_joints`` process.

The messages come from bags played by ``rsrivc_replay`` (raw CDR, its own process: none of its CPU is the node's; one
replay process per block topic). Node CPU is process CPU time over wall time while the bags played (/proc, sampled
every 0.1 s, the replay's start-up left out, scripts/bench_node.py's method); per joint it is the thread CPU of that
joint's worker steps (its pipeline: estimation, fault decision, input stage; status value ``joint_cpu_s``) over the
same window; "shared" is the rest (DDS receive and deserialization in the executor, the one conversion of each
message for all joints, publishing). Lost = samples published - samples aligned per joint. Delay: from the arrival of
a sample's last message to the return of the pipeline update that includes it (the node's ``delay_*_ms``; it includes
the worker period ``block_period_s``, 20 ms by default). ``--baseline`` also runs the same load as one
``rsrivc_monitor`` process per joint (three JointState subscriptions each, or one block topic each).

    python scripts/bench_joints.py [--duration 60] [--cases joints1k joints4k blocks] [--joints 7] [--axes 8]
                                   [--block 100] [--baseline]
"""

from __future__ import annotations

import argparse
import os
import struct
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_node import CpuSampler, play_window, proc_cpu_s  # noqa: E402

from additive_rsrivc_ros.joint_params import JOINT_GROUP_NODE_NAME as NODE  # noqa: E402
from additive_rsrivc_ros.sim import arm  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
T0_NS = 1_700_000_000 * 10**9
TARGETS = {"joints1k": 0.4, "joints4k": 1.0, "blocks": 0.3}
ARM_MEMORY_S = (4.0, 2.0)     # rigid body, flexible mode: baseline learned and fault tests running from 42 s


# ------------------------------------------------------------------------------------------------ bags
def joint_state_cdr(names: list[str], stamps_ns: np.ndarray, fields: dict[str, np.ndarray]) -> list[bytes]:
    """CDR of ``sensor_msgs/JointState`` messages with fixed ``names``: one message serialized by rclpy as the
    template, then the stamp and the values written in place for every sample (vectorized)."""
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import JointState

    n, width = stamps_ns.size, len(names)
    msg = JointState()
    msg.name = list(names)
    sentinel = {f: [1e300 * (1 + 0.01 * (8 * i + j)) for j in range(width)] for i, f in enumerate(fields)}
    for f, vals in sentinel.items():
        setattr(msg, f, vals)
    msg.header.stamp.sec, msg.header.stamp.nanosec = 0x5A5A5A5A, 0x3C3C3C3C
    tpl = np.frombuffer(serialize_message(msg), dtype=np.uint8)
    raw = tpl.tobytes()
    out = np.tile(tpl, (n, 1))
    sec_at, nsec_at = raw.index(struct.pack("<i", 0x5A5A5A5A)), raw.index(struct.pack("<I", 0x3C3C3C3C))
    out[:, sec_at:sec_at + 4] = (stamps_ns // 10**9).astype("<i4").view(np.uint8).reshape(n, 4)
    out[:, nsec_at:nsec_at + 4] = (stamps_ns % 10**9).astype("<u4").view(np.uint8).reshape(n, 4)
    for f, vals in sentinel.items():
        for j, s in enumerate(vals):
            at = raw.index(struct.pack("<d", s))
            out[:, at:at + 8] = np.ascontiguousarray(fields[f][:, j], dtype="<f8").view(np.uint8).reshape(n, 8)
    return [row.tobytes() for row in out]


def write_joint_bag(path: Path, joints: list[arm.ArmJoint], rate_hz: float) -> Path:
    """/joint_commands (position = r) and /joint_states (position = y, effort = u) of every joint, one message each
    per sample, interleaved in time order."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    from additive_rsrivc_ros.io.bagio import SIGNAL_QOS, _typestore, sample_times_ns

    names = [j.name for j in joints]
    n = joints[0].r.size
    ts = sample_times_ns(n, rate_hz, T0_NS)
    cmd = joint_state_cdr(names, ts, {"position": np.column_stack([j.r for j in joints])})
    st = joint_state_cdr(names, ts, {"position": np.column_stack([j.y for j in joints]),
                                     "effort": np.column_stack([j.u for j in joints])})
    writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
    writer.open()
    try:
        conns = [writer.add_connection(t, "sensor_msgs/msg/JointState", typestore=_typestore(),
                                       offered_qos_profiles=[SIGNAL_QOS]) for t in ("/joint_commands", "/joint_states")]
        for k in range(n):
            writer.write(conns[0], int(ts[k]), cmd[k])
            writer.write(conns[1], int(ts[k]), st[k])
    finally:
        writer.close()
    return path


# ------------------------------------------------------------------------------------------------ listener
class Listener:
    """The newest estimator status of every joint (/diagnostics), in its own context."""

    def __init__(self, domain: int, prefix: str) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor

        self.rclpy, self.prefix = rclpy, prefix
        self.ctx = Context()
        rclpy.init(context=self.ctx, domain_id=domain)
        self.node = rclpy.create_node("bench_joints_listener", context=self.ctx)
        self.est: dict[str, dict[str, str]] = {}
        self.cpu: dict[str, list[tuple[float, float]]] = {}
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._diag, 200)
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

    def _diag(self, msg: Any) -> None:
        for st in msg.status:
            if st.name.endswith(": estimator"):
                parts = st.name[: -len(": estimator")].split("/")      # node/joint, or ns/monitor (baseline)
                who = parts[-2] if parts[-1] == "additive_rsrivc_monitor" and len(parts) > 1 else parts[-1]
                self.est[who] = {kv.key: kv.value for kv in st.values}
                cpu = self.est[who].get("joint_cpu_s")
                if cpu is not None:
                    self.cpu.setdefault(who, []).append((time.monotonic(), float(cpu)))

    def cpu_at(self, who: str, t: float) -> float:
        """A joint's cumulative worker CPU (s) at monotonic time ``t`` (linear between its status messages)."""
        pts = self.cpu.get(who, [])
        if len(pts) < 2:
            return float("nan")
        ts, cs = np.array(pts).T
        return float(np.interp(t, ts, cs))

    def close(self) -> None:
        self.rclpy.try_shutdown(context=self.ctx)
        self.th.join(timeout=5)


# ------------------------------------------------------------------------------------------------ one run
def run_case(procs_cmds: list[list[str]], replays: list[list[str]], who: list[str], env: dict, domain: int,
             cpu_key: str | None) -> dict:
    """Start the node process(es), wait for every ``who`` status, play the bags, return the figures."""
    procs = [subprocess.Popen(c, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
             for c in procs_cmds]
    lis = Listener(domain, NODE)
    samplers = [CpuSampler(p.pid) for p in procs]
    try:
        t_wait = time.monotonic()
        while not all(w in lis.est for w in who) and time.monotonic() - t_wait < 90:
            if any(p.poll() is not None for p in procs):
                break
            time.sleep(0.2)
        if not all(w in lis.est for w in who):
            out = [p.communicate(timeout=5)[0] if p.poll() is not None else "" for p in procs]
            raise RuntimeError(f"no status from {sorted(set(who) - set(lis.est))}: {''.join(out)[-2000:]}")
        reps = [subprocess.Popen(c, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
                for c in replays]
        outs = [r.communicate() for r in reps]
        t_end = time.monotonic()
        if any(r.returncode for r in reps):
            raise RuntimeError(f"rsrivc_replay failed: {[o[1].strip() for o in outs]}")
        windows = [play_window(o[0] + o[1], t_end) for o in outs]
        t0, t1 = max(w[0] for w in windows), t_end
        tm = 0.5 * (t0 + t1)      # the second half: after the offline initialization of every joint
        cores = [s.cores(t0, t1) for s in samplers]
        late = [s.cores(tm, t1) for s in samplers]
        time.sleep(3.0)          # drain, then a final status
        est = {w: dict(lis.est[w]) for w in who}
        per = {w: (lis.cpu_at(w, t1) - lis.cpu_at(w, t0)) / (t1 - t0) for w in who} if cpu_key else {}
        per_late = {w: (lis.cpu_at(w, t1) - lis.cpu_at(w, tm)) / (t1 - tm) for w in who} if cpu_key else {}
        alive = all(p.poll() is None for p in procs)
    finally:
        for s in samplers:
            s.close()
        lis.close()
        for p in procs:
            if p.poll() is None:
                p.terminate()
        logs = [p.communicate(timeout=30)[0] for p in procs]
    return {"est": est, "cores": cores, "late": late, "wall": t1 - t0, "per": per, "per_late": per_late,
            "alive": alive, "logs": logs,
            "rc": [p.returncode for p in procs]}


def print_table(title: str, res: dict, n: int, target: float | None, one_process: bool) -> None:
    """Per joint: CPU (whole playback, second half), received, aligned, lost, delay; then shared and total."""
    print(f"\n{title}")
    print(f"{'joint':<10} {'CPU cores':>10} {'2nd half':>9} {'received':>10} {'aligned':>9} {'lost':>6} "
          f"{'delay p50 ms':>13} {'p95 ms':>8} {'max ms':>8}  phase")
    total_lost, sums = 0, [0.0, 0.0]
    for i, (w, e) in enumerate(res["est"].items()):
        cpu = res["per"][w] if one_process else res["cores"][i]
        late = res["per_late"][w] if one_process else res["late"][i]
        sums = [sums[0] + cpu, sums[1] + late]
        aligned = int(e.get("samples_aligned", 0))
        total_lost += n - aligned
        print(f"{w:<10} {cpu:>10.3f} {late:>9.3f} {int(e.get('samples_received', 0)):>10} {aligned:>9} "
              f"{n - aligned:>6} {float(e.get('delay_median_ms', 'nan')):>13.1f} "
              f"{float(e.get('delay_p95_ms', 'nan')):>8.1f} {float(e.get('delay_max_ms', 'nan')):>8.1f}  "
              f"{e.get('phase')}")
    total, total_late = float(sum(res["cores"])), float(sum(res["late"]))
    if one_process:
        print(f"{'shared':<10} {total - sums[0]:>10.3f} {total_late - sums[1]:>9.3f}   (executor: receive, "
              "deserialize; one conversion for all joints; publishing)")
    print(f"{'total':<10} {total:>10.3f} {total_late:>9.3f}   cores over {res['wall']:.1f} s of playback (2nd half: "
          f"after every joint's offline initialization), {len(res['cores'])} process(es); samples lost {total_lost}"
          + (f"; target <= {target:g} core" if target else "") + f"; node(s) alive {res['alive']}; load average "
          f"{os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs")


# ------------------------------------------------------------------------------------------------ cases
def joints_case(rate: float, args: argparse.Namespace, tmp: Path, env: dict, domain: int) -> None:
    names = [f"joint{i + 1}" for i in range(args.joints)]
    t0 = time.monotonic()
    joints = arm.simulate_arm(names, rate, args.duration, seed=0)
    bag = write_joint_bag(tmp / f"arm_{rate:g}", joints, rate)
    n = joints[0].r.size
    params = {**arm.arm_params(names, rate), **({"block_period_s": args.period} if args.period else {})}
    for j in names:               # short memories: every joint monitors (fault tests on) from 42 s of data on
        params[j]["modes"]["memory_s"] = list(ARM_MEMORY_S)
    pfile = tmp / f"arm_{rate:g}.yaml"
    pfile.write_text(yaml.safe_dump({NODE: {"ros__parameters": params}}))
    print(f"\narm: {len(names)} joints, {args.duration:g} s at {rate:g} Hz: {2 * n} JointState messages on 2 topics "
          f"({n} samples per joint; simulated and written in {time.monotonic() - t0:.1f} s)")
    replay = [["rsrivc_replay", str(bag), "--wait-for-subscribers", "60", "--stats"]]
    res = run_case([["rsrivc_joints", "--ros-args", "--params-file", str(pfile)]], replay, names, env, domain,
                   "joint_cpu_s")
    print_table(f"one rsrivc_joints process, {len(names)} joints from /joint_commands + /joint_states at {rate:g} Hz",
                res, n, TARGETS["joints1k" if rate <= 1000 else "joints4k"], True)
    if args.baseline:
        cmds = []
        for k, j in enumerate(names):
            p = {key: v for key, v in params.items() if key not in names and key != "joints"}
            p["modes"] = params[j]["modes"]
            for s, (topic, fld) in {"reference": ("/joint_commands", "position"), "input": ("/joint_states", "effort"),
                                    "output": ("/joint_states", "position")}.items():
                p[s] = {"topic": topic, "type": "sensor_msgs/msg/JointState", "joint": j, "field": fld}
            f = tmp / f"mon_{rate:g}_{k}.yaml"
            f.write_text(yaml.safe_dump({"/**/additive_rsrivc_monitor": {"ros__parameters": p}}))
            cmds.append(["rsrivc_monitor", "--ros-args", "--params-file", str(f), "-r", f"__ns:=/{j}"])
        base = run_case(cmds, replay, names, env, domain, None)
        print_table(f"baseline: {len(names)} rsrivc_monitor processes (3 JointState subscriptions each), same bag",
                    base, n, None, False)


def blocks_case(args: argparse.Namespace, tmp: Path, env: dict, domain: int) -> None:
    from additive_rsrivc_ros.sim import scenarios

    t0 = time.monotonic()
    sc = scenarios.build("beam", duration_s=args.duration, seed=0)
    bag = sc.write_bag(tmp / "beam")
    n = sc.t.size
    axes = [f"axis{i + 1}" for i in range(args.axes)]
    beam = yaml.safe_load((REPO / "config" / "beam.yaml").read_text())["additive_rsrivc_monitor"]["ros__parameters"]
    params = {**beam, "joints": axes, **{a: {"block": {"topic": f"/{a}/block"}} for a in axes},
              **({"block_period_s": args.period} if args.period else {})}
    pfile = tmp / "axes.yaml"
    pfile.write_text(yaml.safe_dump({NODE: {"ros__parameters": params}}))
    print(f"\nbeam: {len(axes)} axes, {args.duration:g} s at {sc.rate_hz:g} Hz, blocks of {args.block} rows "
          f"({n} samples per axis; simulated in {time.monotonic() - t0:.1f} s)")
    replays = [["rsrivc_replay", str(bag), "--block", str(args.block), "--block-topic", f"/{a}/block",
                "--wait-for-subscribers", "60", "--stats"] for a in axes]
    res = run_case([["rsrivc_joints", "--ros-args", "--params-file", str(pfile)]], replays, axes, env, domain,
                   "joint_cpu_s")
    print_table(f"one rsrivc_joints process, {len(axes)} block-input axes at {sc.rate_hz:g} Hz", res, n,
                TARGETS["blocks"], True)
    if args.baseline:
        mon = tmp / "beam_any_ns.yaml"
        mon.write_text(yaml.safe_dump({"/**/additive_rsrivc_monitor": {"ros__parameters": beam}}))
        cmds = [["rsrivc_monitor", "--ros-args", "--params-file", str(mon), "-r", f"__ns:=/{a}", "-p",
                 f"block.topic:=/{a}/block"] for a in axes]
        base = run_case(cmds, replays, axes, env, domain, None)
        print_table(f"baseline: {len(axes)} rsrivc_monitor processes with block input, same bags", base, n, None,
                    False)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration", type=float, default=60.0, help="seconds of data per case (default 60)")
    ap.add_argument("--cases", nargs="+", default=["joints1k", "joints4k", "blocks"],
                    choices=["joints1k", "joints4k", "blocks"])
    ap.add_argument("--joints", type=int, default=7, help="joints of the JointState cases (default 7)")
    ap.add_argument("--axes", type=int, default=8, help="axes of the block case (default 8)")
    ap.add_argument("--block", type=int, default=100, help="rows per block message (default 100)")
    ap.add_argument("--period", type=float, default=0.0, help="block_period_s of rsrivc_joints (default: its own, "
                    "0.05 s)")
    ap.add_argument("--baseline", action="store_true", help="also run one rsrivc_monitor process per joint")
    args = ap.parse_args()
    domain = 150 + os.getpid() % 80
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               OPENBLAS_NUM_THREADS="1", PYTHONUNBUFFERED="1")
    print(f"bench_joints: {' '.join(sys.argv[1:]) or '(defaults)'}; {os.cpu_count()} CPUs, load average "
          f"{os.getloadavg()[0]:.2f} at start")
    with tempfile.TemporaryDirectory(prefix="bench_joints_") as tmp:
        for case in args.cases:
            if case == "blocks":
                blocks_case(args, Path(tmp), env, domain)
            else:
                joints_case(1000.0 if case == "joints1k" else 4000.0, args, Path(tmp), env, domain)
    return 0


if __name__ == "__main__":
    _ = proc_cpu_s       # the CPU reading shared with bench_node.py
    sys.exit(main())
