"""Issue 8 end to end: replay the bundled beam_fault bag into the live node and diagnose it offline.

One estimator and one fault logic (MonitorPipeline): the node's ~/modes stream must equal the offline
estimates.csv report by report (the node synthesizes sample times on the nominal grid, so only float
rounding of absolute times can move a sample across a report instant: we allow 1e-6 relative), and the
fault flags seen on /diagnostics must match the offline events.
"""

from __future__ import annotations

import csv
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

from additive_rsrivc_ros.cli import diagnose
from additive_rsrivc_ros.core.vocabulary import MODE_FIELDS

REPO = Path(__file__).resolve().parents[1]
BAG = REPO / "bags" / "beam_fault"
PARAMS = REPO / "config" / "beam_fault.yaml"
NODE = "additive_rsrivc_monitor"


def test_replay_into_node_matches_offline(tmp_path: Path, ros_env: dict) -> None:
    out = tmp_path / "offline"
    assert diagnose.main([str(BAG), "--params-file", str(PARAMS), "--out", str(out), "--no-report", "--quiet"]) == 0
    with (out / "estimates.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    with (out / "events.csv").open() as fh:
        events = list(csv.DictReader(fh))
    K = 2
    offline = np.array([[float(r[k]) for k in MODE_FIELDS] for r in rows]).reshape(-1, K, 6)
    # DDS between two Python processes at 12288 msg/s on this 2-core machine occasionally loses a burst of one
    # topic (measured: 1 run in 4 to 6, also with the node tolerating 12 s stalls and a 50 ms writer heartbeat), or
    # delivers it late. The node must then say so (count mismatch, resynchronized; or an arrival-rate episode):
    # that is asserted, and the replay is run again (at most three attempts, at the recorded rate: Float64 samples
    # are timed by their arrival, and a replay at another rate is an arrival-rate error with no estimate), which must
    # match exactly. A silent difference fails at once.
    for attempt, rate in ((1, 1.0), (2, 1.0), (3, 1.0)):
        modes, flagged, log, rep = _replay_into_node(ros_env, len(rows) // K, rate)
        live = np.array([m for m in modes if np.all(np.isfinite(m))])
        if live.shape == offline.shape:
            break
        # a burst delivered late also moves the arrival rate off loop_rate_hz for a rate window: the node says so
        # and publishes no estimate meanwhile (an arrival-timed input on a wrong time scale gives no number)
        said = "count mismatch" in log or "no data on" in log or re.search(r"arrival rate \d+ Hz on /", log)
        assert said, (attempt, live.shape, rep.stdout, log[-2000:])
    assert live.shape == offline.shape, (attempt, live.shape, offline.shape, rep.stdout, log[-2000:])
    # A report instant that coincides with a sample time (t * rate integer, e.g. 4.0 s, 4.5 s at 4096 Hz and
    # 10 Hz) is a tie: the node compares absolute ROS times (~1.7e9 s, resolution 2.4e-7 s), the offline run
    # times since the first sample, so float rounding may put that one sample before or after the report.
    # The estimator state is the same afterwards; at a tie the two differ by one sample's update, far below
    # the reported std. Everywhere else the computation is the same: 1e-9 relative.
    t = np.array([float(r["time_s"]) for r in rows[::K]])
    tie = np.abs(t * 4096.0 - np.round(t * 4096.0)) < 1e-6
    np.testing.assert_allclose(live[~tie], offline[~tie], rtol=1e-9, atol=1e-15)
    for q in range(3):
        assert np.all(np.abs(live[tie, :, q] - offline[tie, :, q]) <= offline[tie, :, q + 3])
    offline_faults = {(int(e["mode"]), e["quantity"]) for e in events}
    assert flagged == offline_faults


def _replay_into_node(ros_env: dict, n_expected: int,
                      rate: float = 1.0) -> tuple[list[np.ndarray], set, str, subprocess.CompletedProcess]:
    """Start the node, replay the bag into it over DDS (at ``rate`` x the recorded rate) and collect ~/modes and the
    fault flags on /diagnostics."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.experimental import EventsExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from std_msgs.msg import Float64MultiArray

    os.environ["ROS_DOMAIN_ID"] = ros_env["ROS_DOMAIN_ID"]
    # The bag is continuous: on this shared 2-core machine scheduler stalls of the replay or the node can exceed
    # the default pause detection (sync.gap_s = 50 ms), which would re-prime the filters and change the estimates.
    # Only pauses longer than 2 s count here (documented node parameters, CONTRACT-independent).
    node = subprocess.Popen([sys.executable, "-m", "additive_rsrivc_ros.node", "--ros-args", "--params-file",
                             str(PARAMS), "-p", "sync.gap_s:=2.0", "-p", "sync.hold_s:=1.0"],
                            env=ros_env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=int(ros_env["ROS_DOMAIN_ID"]))
    modes: list[np.ndarray] = []
    flagged: set[tuple[int, str]] = set()
    done = threading.Event()
    try:
        sub = rclpy.create_node("e2e_listener", context=ctx)
        qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        sub.create_subscription(Float64MultiArray, f"/{NODE}/modes",
                                lambda m: modes.append(np.asarray(m.data, float).reshape(-1, 6)), qos)

        def on_diag(msg: DiagnosticArray) -> None:
            for st in msg.status:
                if ": mode " not in st.name:
                    continue
                i = int(st.name.rsplit(" ", 1)[-1])
                for kv in st.values:
                    if kv.key.startswith("fault_") and kv.value == "true":
                        flagged.add((i, kv.key[len("fault_"):]))

        sub.create_subscription(DiagnosticArray, "/diagnostics", on_diag, qos)
        ex = EventsExecutor(context=ctx)
        ex.add_node(sub)

        def spin() -> None:
            while not done.is_set():
                ex.spin_once(timeout_sec=0.1)

        th = threading.Thread(target=spin, daemon=True)
        th.start()
        rep = subprocess.run([sys.executable, "-m", "additive_rsrivc_ros.cli.replay", str(BAG), "--topics",
                              "/reference", "/plant_input", "/plant_output", "--wait-for-subscribers", "60",
                              "--rate", str(rate), "--stats"], env=ros_env, capture_output=True, text=True,
                             timeout=90 + 60 / rate)
        assert rep.returncode == 0, rep.stderr
        deadline = time.monotonic() + 15.0
        while time.monotonic() < deadline and sum(np.all(np.isfinite(m)) for m in modes) < n_expected:
            time.sleep(0.2)
        time.sleep(1.0)
        done.set()
        th.join(5.0)
        ex.remove_node(sub)
        sub.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)
        node.send_signal(signal.SIGINT)
        try:
            log = node.communicate(timeout=20)[0]
        except subprocess.TimeoutExpired:
            node.kill()
            log = node.communicate()[0]
    return modes, flagged, log, rep
