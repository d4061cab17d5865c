"""rsrivc_joints as a subprocess over real DDS (localhost, own domain): one process, three joints with different plants
read from the two shared JointState topics a robot publishes.

Reference: each joint's own offline :class:`MonitorPipeline` fed that joint's samples (the node is a shell around one
pipeline per joint; with stamped inputs and no loss its ~/<joint>/modes must equal the offline reports to rounding).
A wrong column (another joint's data, effort and position swapped) gives another plant and fails the equality; the
offline pipelines themselves are checked against the simulation truth (the plants differ by 20-50 % in frequency) and
against the fault schedule (flagged on the faulty joint only), so the test data can show what it claims.
"""
import math
import subprocess
import sys
import time

import numpy as np
import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from test_node_helpers import DATA_QOS, stop_node

from additive_rsrivc_ros.config import MonitorConfig, _flatten, validate_params
from additive_rsrivc_ros.core.monitor.pipeline import MonitorPipeline
from additive_rsrivc_ros.ros.convert import MODE_KEYS
from additive_rsrivc_ros.sim import arm

NODE = "additive_rsrivc_joints"
RATE = 1000.0
JOINTS = ["shoulder", "elbow", "wrist"]
MEMORY = [4.0, 2.0]                  # short memories: the baseline is learned by 42 s (settle 3 x 4 s, learn 5 x 4 s)
FAULT_JOINT, FAULT_S, DURATION_S = "elbow", 50.0, 62.0
MISSING = (30_000, 30_100)           # samples whose /joint_states message lacks the wrist
LOST = (20_000, 20_050)              # samples whose /joint_states message is never published (lost for every joint)
T0_NS = 1_000 * 10**9


def _params_file(tmp_path) -> str:
    import yaml

    p = arm.arm_params(JOINTS, RATE)
    for j in JOINTS:
        p[j]["modes"]["memory_s"] = list(MEMORY)
    p["diagnostics_period_s"] = 0.2
    p["qos_depth"] = 100_000
    path = tmp_path / "joints.yaml"
    path.write_text(yaml.safe_dump({NODE: {"ros__parameters": p}}))
    return str(path)


def _offline(t: np.ndarray, j: arm.ArmJoint, keep: np.ndarray):
    """The joint's own pipeline over the samples the node gets (``keep``), as the node configures it."""
    p = arm.arm_params(JOINTS, RATE)
    flat = _flatten({key: v for key, v in p.items() if key not in JOINTS and key != "joints"})
    flat.update(_flatten({"modes": {**p[j.name]["modes"], "memory_s": MEMORY}}))
    flat.update({f"{s}.type": "sensor_msgs/msg/JointState" for s in ("reference", "input", "output")})
    pipe = MonitorPipeline(MonitorConfig.from_params(validate_params(flat)))
    return pipe.push(t[keep], j.r[keep], j.u[keep], j.y[keep])


def _sim_clock(robot: "Robot", speed: float):
    """Publish /clock at ``speed`` x wall time from 1000 s on; returns the function that stops it."""
    import threading

    from builtin_interfaces.msg import Time
    from rosgraph_msgs.msg import Clock

    pub = robot.node.create_publisher(Clock, "/clock", 10)
    stop = threading.Event()
    t0 = time.monotonic()

    def loop() -> None:
        while not stop.wait(0.01):
            ns = int((1000.0 + speed * (time.monotonic() - t0)) * 1e9)
            try:
                pub.publish(Clock(clock=Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)))
            except Exception:  # noqa: BLE001 - context shut down
                return
    th = threading.Thread(target=loop, daemon=True)
    th.start()
    return stop.set


class Robot:
    """Publishes /joint_commands and /joint_states; listens to /diagnostics and every ~/<joint>/modes."""

    def __init__(self, domain: int) -> None:
        self.ctx = Context()
        rclpy.init(context=self.ctx, domain_id=domain)
        self.node = rclpy.create_node("robot", context=self.ctx)
        self.cmd = self.node.create_publisher(JointState, "/joint_commands", DATA_QOS)
        self.states = self.node.create_publisher(JointState, "/joint_states", DATA_QOS)
        self.diags: list[DiagnosticArray] = []
        self.modes: dict[str, list] = {j: [] for j in JOINTS}
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self.diags.append, 100)
        for j in JOINTS:
            self.node.create_subscription(Float64MultiArray, f"/{NODE}/{j}/modes", self.modes[j].append, 100)
        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.ex.add_node(self.node)
        import threading
        self.th = threading.Thread(target=self._spin, daemon=True)
        self.th.start()

    def _spin(self) -> None:
        try:
            while self.ctx.ok():
                self.ex.spin_once(timeout_sec=0.05)
        except Exception:  # noqa: BLE001 - context shut down
            pass

    def status(self, joint: str, suffix: str) -> dict | None:
        for arr in reversed(self.diags):
            for st in arr.status:
                if st.name == f"{NODE}/{joint}: {suffix}":
                    return {"level": st.level[0], "message": st.message, "keys": [kv.key for kv in st.values],
                            "values": {kv.key: kv.value for kv in st.values}}
        return None

    def wait_for(self, pred, timeout: float, what: str) -> None:
        t_end = time.monotonic() + timeout
        while time.monotonic() < t_end:
            if pred():
                return
            time.sleep(0.1)
        raise AssertionError(f"timed out after {timeout} s waiting for {what}")

    def close(self) -> None:
        rclpy.try_shutdown(context=self.ctx)
        self.th.join(timeout=5)


def _publish(robot: Robot, joints: list[arm.ArmJoint], stamps: np.ndarray) -> None:
    """Commands name the joints in another order than the states, and the states carry a joint nobody monitors."""
    cmd_order = [2, 0, 1]
    n = stamps.size
    for k in range(n):
        sec, nsec = int(stamps[k] // 10**9), int(stamps[k] % 10**9)
        c = JointState()
        c.header.stamp.sec, c.header.stamp.nanosec = sec, nsec
        c.name = [JOINTS[i] for i in cmd_order]
        c.position = [float(joints[i].r[k]) for i in cmd_order]
        s = JointState()
        s.header.stamp.sec, s.header.stamp.nanosec = sec, nsec
        idx = [0, 1] if MISSING[0] <= k < MISSING[1] else [0, 1, 2]
        s.name = [JOINTS[i] for i in idx] + ["gripper"]
        s.position = [float(joints[i].y[k]) for i in idx] + [0.01]
        s.effort = [float(joints[i].u[k]) for i in idx] + [-1.0]
        robot.cmd.publish(c)
        if not LOST[0] <= k < LOST[1]:
            robot.states.publish(s)
        if k % 100 == 99:
            time.sleep(0.03)         # about 3x real time


def test_three_joints_from_shared_joint_state_topics(ros_env, tmp_path):
    dom = int(ros_env["ROS_DOMAIN_ID"])
    joints = arm.simulate_arm(JOINTS, RATE, DURATION_S, seed=5, fault_joint=FAULT_JOINT, fault_time_s=FAULT_S)
    n = joints[0].r.size
    stamps = T0_NS + np.arange(n, dtype=np.int64) * 1_000_000
    t = stamps * 1e-9
    keep = {j: np.ones(n, dtype=bool) for j in JOINTS}
    keep["wrist"][MISSING[0]:MISSING[1]] = False
    for j in JOINTS:
        keep[j][LOST[0]:LOST[1]] = False
    ref = {j.name: _offline(t, j, keep[j.name]) for j in joints}
    # the test data show what they claim: each offline pipeline on its own plant, the fault on the elbow only
    for j in joints:
        last = ref[j.name][-1]
        assert last.phase == "monitoring", (j.name, last.phase)
        rel = np.abs(last.modal[1, :3] - j.truth[1, -1]) / j.truth[1, -1]
        assert rel[0] < 0.01, (j.name, last.modal[1], j.truth[1, -1])   # flexible-mode frequency within 1 %
        assert bool(last.flags.any()) == (j.name == FAULT_JOINT), (j.name, last.flags)

    proc = subprocess.Popen(["rsrivc_joints", "--ros-args", "--params-file", _params_file(tmp_path)], env=ros_env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    robot = Robot(dom)
    try:
        robot.wait_for(lambda: robot.cmd.get_subscription_count() > 0 and robot.states.get_subscription_count() > 0,
                       60, "the node's two subscriptions")
        robot.wait_for(lambda: all(robot.status(j, "mode 2") is not None for j in JOINTS), 30, "STALE statuses")
        assert all(robot.status(j, "mode 1")["level"] == 3 for j in JOINTS)
        assert robot.status("shoulder", "mode 1")["keys"] == list(MODE_KEYS)
        _publish(robot, joints, stamps)

        def caught_up(j: str) -> bool:
            got = robot.modes[j]
            return bool(got) and np.allclose(np.asarray(got[-1].data), ref[j][-1].modal.ravel(), rtol=1e-9, atol=0.0)
        robot.wait_for(lambda: all(caught_up(j) for j in JOINTS), 120, "every joint's ~/modes equal to its own "
                       "offline pipeline's last report")
        # samples are counted when aligned, before the worker has made the report from them: wait for both
        def settled(j: str) -> bool:
            aligned = int(robot.status(j, "estimator")["values"]["samples_aligned"]) == keep[j].sum()
            freqs = [float(robot.status(j, f"mode {i + 1}")["values"]["natural_frequency_hz"]) for i in range(2)]
            return aligned and bool(np.allclose(freqs, ref[j][-1].modal[:2, 0], rtol=1e-9, atol=0.0))
        robot.wait_for(lambda: all(settled(j) for j in JOINTS), 20, "final counters and statuses")
        for j in JOINTS:
            est = robot.status(j, "estimator")["values"]
            lost = MISSING[1] - MISSING[0] if j == "wrist" else 0
            # nothing lost in DDS; the wrist's input and output are missing from `lost` messages, whose references
            # then have no partner, as every joint's references of the unpublished /joint_states messages
            gone = LOST[1] - LOST[0]
            assert int(est["samples_received"]) == 3 * n - 2 * lost - 2 * gone, (j, est["samples_received"])
            assert int(est["queue_dropped"]) == 0 and int(est["misaligned_events"]) == 0, j
            assert int(est["malformed_messages"]) == 2 * lost, (j, est)
            assert int(est["unmatched_messages"]) == lost + gone, (j, est)
            assert est["joint"] == j and math.isfinite(float(est["joint_cpu_fraction"]))
            assert math.isfinite(float(est["delay_median_ms"]))
            for i in range(2):
                st = robot.status(j, f"mode {i + 1}")
                flagged = [st["values"][k] for k in MODE_KEYS[-3:]]
                want = ["true" if f else "false" for f in ref[j][-1].flags[i]]
                assert flagged == want, (j, i, flagged, want)
                assert (st["level"] == 2) == (j == FAULT_JOINT and i == 1), (j, i, st)
                np.testing.assert_allclose(float(st["values"]["natural_frequency_hz"]), ref[j][-1].modal[i, 0],
                                           rtol=1e-9)
        assert "fault" in robot.status(FAULT_JOINT, "mode 2")["message"]
    finally:
        robot.close()
        rc, out = stop_node(proc, "TERM")
    assert rc == 0, out
    assert "Traceback" not in out, out
    assert out.count("joint 'wrist' not in") == 1, out    # the missing joint: one line for its one episode


@pytest.mark.parametrize("override, expect", [
    ("joints:=[shoulder, shoulder]", "names shoulder more than once"),
    ("elbw.modes.memory_s:=[1.0, 1.0]", "'elbw' is not one of the joints"),
    ("elbow.qos_depth:=10", "one value for the whole node"),
    ("elbow.modes.memry_s:=[1.0, 1.0]", "did you mean elbow.modes.memory_s"),
])
def test_bad_joint_parameters_are_one_line_errors(ros_env, tmp_path, override, expect):
    r = subprocess.run(["rsrivc_joints", "--ros-args", "--params-file", _params_file(tmp_path), "-p", override],
                       env=ros_env, capture_output=True, text=True, timeout=60)
    assert r.returncode == 1 and expect in r.stderr and "Traceback" not in r.stderr + r.stdout, r.stderr + r.stdout


def test_help_needs_no_ros():
    r = subprocess.run([sys.executable, "-m", "additive_rsrivc_ros.joints_node", "--help"], capture_output=True,
                       text=True, timeout=60)
    assert r.returncode == 0 and "~/<joint>/modes" in r.stdout


def test_bundled_arm_params_configure_the_first_n_joints(ros_env, repo):
    """rcl parses config/joints/arm.yaml (the launch file's default) under a namespace; monitor_joints and joint_count
    (the launch arguments joints and count) pick the joints; the other joints' sections are no error."""
    params = str(repo / "config" / "joints" / "arm.yaml")
    proc = subprocess.Popen(["rsrivc_joints", "--ros-args", "-r", "__ns:=/arm", "--params-file", params, "-p",
                             "monitor_joints:=[joint6, joint2, joint4]", "-p", "joint_count:=2"],
                            env=ros_env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines = []
    t_end = time.monotonic() + 60
    try:
        while time.monotonic() < t_end:
            line = proc.stdout.readline()
            if not line:
                break
            lines.append(line)
            if "configured:" in line:
                break
    finally:
        rc, out = stop_node(proc, "INT")
    text = "".join(lines) + out
    assert rc == 0 and "configured: 2 joints (joint6, joint2)" in text and "Traceback" not in text, text
    assert "/arm/joint_states (4 signals)" in text and "ignoring" not in text, text


def test_block_input_axes_in_one_process(ros_env, tmp_path):
    """Two axes with block input, each on its own block topic, in one process: every row arrives, each axis tracks
    its own plant (flexible modes 6 and 7.5 Hz: 25 % apart, estimated within 1 %)."""
    import yaml

    from additive_rsrivc_ros.ros.convert import block_message

    axes = ["axis1", "axis2"]
    p = arm.arm_params(axes, RATE)
    for a in axes:
        p[a]["block"] = {"topic": f"/{a}/block"}
    p["diagnostics_period_s"] = 0.2
    # the blocks go out at 5x real time; block indices carry no time, so the node's clock must say so (as
    # rsrivc_replay --clock does): a simulated /clock at 5x wall time, else the arrival rate is a rate error
    p["use_sim_time"] = True
    path = tmp_path / "axes.yaml"
    path.write_text(yaml.safe_dump({NODE: {"ros__parameters": p}}))
    data = arm.simulate_arm(axes, RATE, 30.0, seed=2)
    n = data[0].r.size
    proc = subprocess.Popen(["rsrivc_joints", "--ros-args", "--params-file", str(path)], env=ros_env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    robot = Robot(int(ros_env["ROS_DOMAIN_ID"]))
    pubs = {a: robot.node.create_publisher(Float64MultiArray, f"/{a}/block", DATA_QOS) for a in axes}
    stop_clock = _sim_clock(robot, speed=5.0)
    try:
        robot.wait_for(lambda: all(pb.get_subscription_count() > 0 for pb in pubs.values()), 60, "block subscriptions")
        rows, t_next = 100, time.monotonic()
        for k in range(0, n, rows):
            for a, j in zip(axes, data, strict=True):
                sl = slice(k, k + rows)
                pubs[a].publish(block_message(np.arange(n)[sl], j.r[sl], j.u[sl], j.y[sl]))
            t_next += 0.02                     # 100 rows of a 1 kHz loop per 0.02 s: 5x real time, paced
            time.sleep(max(0.0, t_next - time.monotonic()))
        robot.wait_for(lambda: all((robot.status(a, "estimator") or {"values": {}})["values"].get("samples_aligned")
                                   == str(n) for a in axes), 60, "every row of both axes")
        robot.wait_for(lambda: all(robot.status(a, "mode 2")["values"]["natural_frequency_hz"] != "nan"
                                   for a in axes), 30, "estimates")
        for a, j in zip(axes, data, strict=True):
            est = robot.status(a, "estimator")["values"]
            assert int(est["block_missing_samples"]) == 0 and int(est["queue_dropped"]) == 0, est
            f = float(robot.status(a, "mode 2")["values"]["natural_frequency_hz"])
            assert abs(f / j.truth[1, -1, 0] - 1.0) < 0.01, (a, f, j.truth[1, -1, 0])
    finally:
        stop_clock()
        robot.close()
        rc, out = stop_node(proc, "TERM")
    assert rc == 0 and "Traceback" not in out, out
    assert "block input: axis1, axis2" in out, out


def test_runtime_parameters_and_services_per_joint(ros_env, tmp_path):
    """A shared runtime change reaches every joint without its own value; a joint's own value is checked against
    that joint (the rejection names it); read-only stays read-only; each joint has its own services."""
    from rclpy.parameter import Parameter
    from test_node_helpers import Client

    path = _params_file(tmp_path)
    proc = subprocess.Popen(["rsrivc_joints", "--ros-args", "--params-file", path, "-p",
                             "elbow.faults.min_change.natural_frequency:=0.04"], env=ros_env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    cli = Client(int(ros_env["ROS_DOMAIN_ID"]), JointState, node=NODE)
    try:
        ok = cli.set_params([Parameter("faults.min_change.natural_frequency", Parameter.Type.DOUBLE, 0.03)])
        assert ok[0].successful, ok[0].reason
        got = cli.get_params(["faults.min_change.natural_frequency", "elbow.faults.min_change.natural_frequency"])
        assert [g.double_value for g in got] == [0.03, 0.04]
        bad = cli.set_params([Parameter("elbow.modes.memory_s", Parameter.Type.DOUBLE_ARRAY, [1.0, 1.0, 1.0])])[0]
        assert not bad.successful and "joint 'elbow'" in bad.reason and "entries" in bad.reason, bad.reason
        assert cli.set_params([Parameter("elbow.modes.memory_s", Parameter.Type.DOUBLE_ARRAY, [3.0, 1.5])])[0] \
            .successful
        ro = cli.set_params([Parameter("loop_rate_hz", Parameter.Type.DOUBLE, 500.0)])[0]
        assert not ro.successful and "read-only" in ro.reason
        for j in JOINTS:
            r = cli.trigger(f"{j}/reset")
            assert r.success, (j, r.message)
        assert not cli.trigger("elbow/save_state").success      # no state_file: says so
    finally:
        cli.close()
        rc, out = stop_node(proc, "TERM")
    assert rc == 0 and "Traceback" not in out, out
    assert "[additive_rsrivc_joints.elbow]: applied modes.memory_s=[3.0, 1.5]" in out, out
    assert out.count("applied faults.min_change.natural_frequency=0.03") == 2, out      # shoulder and wrist only


def test_lifecycle_transitions_rebuild_every_joint(ros_env, tmp_path):
    """autostart false: unconfigured and silent; configure, activate, deactivate, cleanup, configure, activate again
    through the lifecycle services: every joint's statuses come back and the process ends cleanly."""
    from lifecycle_msgs.msg import Transition
    from lifecycle_msgs.srv import ChangeState, GetState
    from test_node_helpers import Client

    proc = subprocess.Popen(["rsrivc_joints", "--ros-args", "--params-file", _params_file(tmp_path), "-p",
                             "autostart:=false"], env=ros_env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)
    cli = Client(int(ros_env["ROS_DOMAIN_ID"]), JointState, node=NODE)
    robot = Robot(int(ros_env["ROS_DOMAIN_ID"]))

    def change(tid: int) -> bool:
        req = ChangeState.Request()
        req.transition.id = tid
        return cli._call(ChangeState, f"/{NODE}/change_state", req).success
    try:
        assert cli._call(GetState, f"/{NODE}/get_state", GetState.Request()).current_state.label == "unconfigured"
        time.sleep(1.0)
        assert not robot.diags, "an unconfigured node must not publish"
        T = Transition
        for tids in ((T.TRANSITION_CONFIGURE, T.TRANSITION_ACTIVATE),
                     (T.TRANSITION_DEACTIVATE, T.TRANSITION_CLEANUP, T.TRANSITION_CONFIGURE, T.TRANSITION_ACTIVATE)):
            robot.diags.clear()
            assert all(change(t) for t in tids)
            robot.wait_for(lambda: all(robot.status(j, "estimator") is not None for j in JOINTS), 20,
                           "every joint's status after activation")
        assert cli._call(GetState, f"/{NODE}/get_state", GetState.Request()).current_state.label == "active"
    finally:
        robot.close()
        cli.close()
        rc, out = stop_node(proc, "INT")
    assert rc == 0 and "Traceback" not in out, out
    assert out.count("configured: 3 joints") == 2, out
