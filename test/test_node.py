"""rsrivc_monitor as a subprocess over real DDS (localhost, own domain): estimates, CONTRACT outputs, runtime
parameters, services, state persistence across a restart, bad inputs, clean shutdown.

The estimation reference is the offline :class:`MonitorPipeline` fed the same samples in the test process:
the node is a shell around it, so with stamped (JointState) inputs and no loss its ~/modes must equal the
offline reports to rounding. Accuracy against the simulation truth is checked with the recursive engine's
validated error level (sim/experiments.py LIMITS, 10-seed mean RMS relative error in %), allowing
4x for a single seed at a single instant.
"""
import math
import re
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import rclpy  # noqa: E402
from rclpy.context import Context  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from std_msgs.msg import Float64, String  # noqa: E402
from test_node_helpers import Client, cloud_table, start_node, stop_node  # noqa: E402

from additive_rsrivc_ros.config import MonitorConfig, load_params_file, render_params_yaml  # noqa: E402
from additive_rsrivc_ros.core.monitor.pipeline import MonitorPipeline  # noqa: E402
from additive_rsrivc_ros.core.vocabulary import FLAG_FIELDS  # noqa: E402
from additive_rsrivc_ros.ros.convert import MODE_KEYS  # noqa: E402
from additive_rsrivc_ros.sim import scenarios  # noqa: E402
from additive_rsrivc_ros.sim.experiments import LIMITS

REPO = Path(__file__).resolve().parents[1]
PAPER = str(REPO / "config" / "paper_example.yaml")

STAMPED = [f"{s}.type:=sensor_msgs/msg/JointState" for s in ("reference", "input", "output")]


def _joint(ns: int, value: float) -> JointState:
    m = JointState()
    m.header.stamp.sec, m.header.stamp.nanosec = ns // 10**9, ns % 10**9
    m.name = ["j"]
    m.position = [value]
    return m


def _levels_ok(st: dict) -> bool:
    return st is not None and st["level"] in (0, 1, 2, 3)


def test_stamped_inputs_params_services_and_restart(ros_env, tmp_path):
    dom = int(ros_env["ROS_DOMAIN_ID"])
    state = tmp_path / "state.json"
    memory = 20.0
    overrides = [*STAMPED, "qos_depth:=30000", f"state_file:={state}", "stale_timeout_s:=30.0",
                 f"modes.memory_s:=[{memory}, {memory}, {memory}]"]
    # one record of 580 s: the first 280 s before the node is killed, no drift (the truth is the initial plant, 000
    # §5); the rest after the restart, with a real change 2 s after the data resume (omega1 -20 %, zeta2 -50 %)
    full = scenarios.build("paper_example", duration_s=580.0, seed=3, drift1_start_s=282.0, drift1_end_s=284.0,
                           drift2_start_s=1.2e4, drift2_end_s=1.3e4)
    n = 5600
    sc = SimpleNamespace(t=full.t[:n], r=full.r[:n], u=full.u[:n], y=full.y[:n], truth=full.truth[:, :n])
    h_ns = 50_000_000
    stamps = 1_000 * 10**9 + np.arange(full.t.size, dtype=np.int64) * h_ns

    proc = start_node(ros_env, PAPER, *overrides)
    cli = Client(dom, JointState)
    try:
        cli.wait_matched()
        # before any data: every mode STALE, exactly the CONTRACT keys
        cli.wait_for(lambda: cli.status("mode 3") is not None, 20, "a STALE mode status")
        st = cli.status("mode 1")
        assert st["level"] == 3 and st["keys"] == list(MODE_KEYS)
        assert cli.status("estimator")["level"] == 3
        data = {"reference": sc.r, "input": sc.u, "output": sc.y}
        for k in range(n):
            for s, p in cli.pubs.items():
                p.publish(_joint(int(stamps[k]), float(data[s][k])))
            if k % 200 == 199:
                time.sleep(0.05)
        # the same samples through the offline pipeline
        params = load_params_file(PAPER)
        params["modes.memory_s"] = [memory] * 3
        params.update({f"{s}.type": "sensor_msgs/msg/JointState" for s in ("reference", "input", "output")})
        pipe = MonitorPipeline(MonitorConfig.from_params(params))     # as the node: stamped, paired exactly
        reports = pipe.push(stamps[:n] * 1e-9, sc.r, sc.u, sc.y)
        ref = reports[-1]
        assert ref.phase == "monitoring", "test data too short to learn a baseline"

        def caught_up() -> bool:
            return bool(cli.modes) and np.allclose(np.asarray(cli.modes[-1].data), ref.modal.ravel(), rtol=1e-9,
                                                   atol=0.0, equal_nan=True)
        cli.wait_for(caught_up, 90, "~/modes equal to the offline pipeline's last report")
        m = cli.modes[-1]
        assert [(d.label, d.size) for d in m.layout.dim] == [("mode", 3), ("field", 6)]
        # ~/modes_stamped: the same estimate, its named fields, stamped with the data time of the report: the
        # stamp of the sample it was made at (the offline pipeline's origin + time_s, to float64 rounding of 2e9 s)
        def rows(msg) -> np.ndarray:
            return np.column_stack([cloud_table(msg)[f] for f in MODE_KEYS[:6]])

        def stamped_of_m() -> list:
            return [x for x in cli.stamped if np.array_equal(rows(x), np.reshape(m.data, (3, 6)), equal_nan=True)]
        cli.wait_for(lambda: bool(stamped_of_m()), 10, "~/modes_stamped with the values of the last ~/modes")
        sm = stamped_of_m()[-1]
        table = cloud_table(sm)
        assert table.dtype.names == ("mode", *MODE_KEYS[:6]) and table["mode"].tolist() == [1, 2, 3]
        stamp_ns = sm.header.stamp.sec * 10**9 + sm.header.stamp.nanosec
        k_rep = int(np.argmin(np.abs(stamps - stamp_ns)))
        assert abs(int(stamps[k_rep]) - stamp_ns) <= 1_000, (stamp_ns, stamps[k_rep])
        assert abs((pipe.t0 + ref.time_s) * 1e9 - stamp_ns) <= 1_000
        got_s = [m_.header.stamp.sec + m_.header.stamp.nanosec * 1e-9 for m_ in cli.stamped]
        assert np.all(np.diff(got_s) > 0)                   # one per report, in data-time order
        est = cli.status("estimator")["values"]
        assert int(est["samples_aligned"]) == n and int(est["samples_dropped"]) == 0
        assert int(est["misaligned_events"]) == 0 and int(est["gaps"]) == 0
        assert float(est["real_time_factor"]) > 1.0 and math.isfinite(float(est["delay_median_ms"]))
        modal = np.asarray(m.data).reshape(3, 6)
        truth = sc.truth[:, -1, :]
        rel = np.abs(modal[:, :3] - truth) / np.abs(truth)
        # the node already equals the offline pipeline here: a failure below is an estimator (core) problem
        assert np.all(rel <= 4 * LIMITS / 100), ("offline pipeline and node off the truth by (%)",
                                                    np.round(100 * rel, 2))
        cli.wait_for(lambda: cli.status("mode 1")["values"]["baseline_gain"] != "nan", 20, "baseline on /diagnostics")
        for i in range(3):
            st = cli.status(f"mode {i + 1}")
            assert st["keys"] == list(MODE_KEYS)
            vals = {k: st["values"][k] for k in MODE_KEYS}
            assert all(vals[k] in ("true", "false") for k in MODE_KEYS[-3:])
            np.testing.assert_allclose(float(vals["natural_frequency_hz"]), ref.modal[i, 0], rtol=1e-9)
            np.testing.assert_allclose(float(vals["baseline_gain"]), ref.baseline[i, 2], rtol=1e-9)
        # the estimate after the last sample (a few samples later than the last report)
        saved_modal, saved_baseline = pipe.modal().copy(), ref.baseline.copy()

        # ---- runtime parameters from another process
        ok = cli.set_params([Parameter("modes.memory_s", Parameter.Type.DOUBLE_ARRAY, [30.0, 30.0, 30.0]),
                             Parameter("faults.min_change.natural_frequency", Parameter.Type.DOUBLE, 0.05)])
        assert all(r.successful for r in ok), [r.reason for r in ok]
        got = cli.get_params(["modes.memory_s", "faults.min_change.natural_frequency"])
        assert list(got[0].double_array_value) == [30.0, 30.0, 30.0] and got[1].double_value == 0.05
        assert cli.set_params([Parameter("publish_rate_hz", Parameter.Type.INTEGER, 5)])[0].successful
        assert cli.get_params(["publish_rate_hz"])[0].double_value == 5.0       # int accepted for a double
        bad = {
            "publish_rate_hz": Parameter("publish_rate_hz", Parameter.Type.DOUBLE, 5000.0),
            "memory_s": Parameter("modes.memory_s", Parameter.Type.DOUBLE_ARRAY, [0.01, 0.01, 0.01]),
            "entries": Parameter("modes.memory_s", Parameter.Type.DOUBLE_ARRAY, [30.0, 30.0]),  # K = 3
            "read-only": Parameter("loop_rate_hz", Parameter.Type.DOUBLE, 100.0),
            "type": Parameter("faults.min_change.gain", Parameter.Type.STRING, "big"),
        }
        for what, p in bad.items():
            r = cli.set_params([p])[0]
            assert not r.successful and r.reason, what
        assert "range" in cli.set_params([bad["publish_rate_hz"]])[0].reason
        assert "entries" in cli.set_params([bad["entries"]])[0].reason
        assert "read-only" in cli.set_params([bad["read-only"]])[0].reason
        assert cli.get_params(["modes.memory_s"])[0].double_array_value.tolist() == [30.0, 30.0, 30.0]

        # ---- services, then the process is killed (SIGKILL: no shutdown, no save at exit)
        r = cli.trigger("save_state")
        assert r.success and state.is_file()
        saved_at_request = state.read_text()
    finally:
        cli.close()
        proc.kill()
        out, _ = proc.communicate(timeout=30)
    assert proc.returncode == -9, out
    assert "Traceback" not in out and "applied modes.memory_s=[30.0, 30.0, 30.0]" in out
    assert state.read_text() == saved_at_request          # the kill wrote nothing

    # ---- restart from the saved state: the estimate and the baseline continue (no new data yet)
    proc = start_node(ros_env, PAPER, *overrides)
    cli = Client(dom, JointState)
    try:
        cli.wait_for(lambda: cli.status("estimator") is not None, 30, "diagnostics after restart")
        est = cli.status("estimator")
        assert est["values"]["phase"] == "monitoring", est
        for i in range(3):
            v = cli.status(f"mode {i + 1}")["values"]
            np.testing.assert_allclose(float(v["natural_frequency_hz"]), saved_modal[i, 0], rtol=1e-12)
            np.testing.assert_allclose(float(v["gain"]), saved_modal[i, 2], rtol=1e-12)
            np.testing.assert_allclose(float(v["baseline_gain"]), saved_baseline[i, 2], rtol=1e-12)
        # the rest of the record, with a real change 2 s after the data resume: the node continues the restored
        # estimate and ends exactly where the record without the kill ends (the offline pipeline, uninterrupted; the
        # memories are the parameter's again, as the node says), and the change is not masked
        pipe.update_params({"modes.memory_s": [30.0, 30.0, 30.0]})   # as the node before the kill (the memory
        pipe.update_params({"modes.memory_s": [memory] * 3})          # change rescales the covariance: rounding)
        final = pipe.push(stamps[n:] * 1e-9, full.r[n:], full.u[n:], full.y[n:])[-1]
        levels = final.mode_levels.tolist()
        assert levels[0] >= 1 and levels[2] == 0, ("the change is masked, or blamed on mode 3", final.decisions)
        cli.wait_matched()
        for k in range(n, full.t.size):
            for s, p in cli.pubs.items():
                p.publish(_joint(int(stamps[k]), float({"reference": full.r, "input": full.u, "output": full.y}[s][k])))
            if k % 200 == 199:
                time.sleep(0.05)
        cli.wait_for(lambda: bool(cli.modes) and np.allclose(np.asarray(cli.modes[-1].data), final.modal.ravel(),
                                                             rtol=1e-9, atol=0.0, equal_nan=True), 90,
                     "~/modes equal to the uninterrupted offline pipeline's last report")
        ev = cli.status("estimator")["values"]
        assert ev["initializations"] == "1" and ev["phase"] == "monitoring", ev
        for i in range(3):       # judged against the baseline learned before the kill, as the offline run
            st = cli.status(f"mode {i + 1}")
            np.testing.assert_allclose(float(st["values"]["baseline_gain"]), saved_baseline[i, 2], rtol=1e-12)
            assert st["level"] == levels[i], (i, st["message"], final.decisions[i])
            assert [st["values"][k] == "true" for k in FLAG_FIELDS] == final.flags[i].tolist(), st
        # a new baseline is asked for: the open events close (the baseline is learned again from the next data)
        r = cli.trigger("rebaseline")
        closed = re.search(r"(\d+) open fault event\(s\) closed", r.message)
        assert r.success and closed and int(closed.group(1)) == int(final.flags.sum()), r.message
    finally:
        cli.close()
        rc, out = stop_node(proc, "INT")
    assert rc == 0, out
    assert "the state was saved with modes.memory_s=[30.0, 30.0, 30.0]; the parameter's [20.0, 20.0, 20.0] applies" \
        in out, out


def test_float64_bad_inputs_are_reported_and_survived(ros_env):
    dom = int(ros_env["ROS_DOMAIN_ID"])
    rate = 200.0
    proc = start_node(ros_env, PAPER, f"loop_rate_hz:={rate}", "stale_timeout_s:=0.5", "qos_depth:=5000")
    cli = Client(dom, Float64)
    rng = np.random.default_rng(0)
    k = [0]

    def publish(seconds: float, signals=("reference", "input", "output"), nan_every: int = 0) -> None:
        t0 = time.monotonic()
        for j in range(int(seconds * rate)):
            k[0] += 1
            for s in signals:
                v = float(rng.standard_normal())
                if s == "output" and nan_every and j % nan_every == 0:
                    v = math.nan
                cli.pubs[s].publish(Float64(data=v))
            lag = t0 + (j + 1) / rate - time.monotonic()
            if lag > 0:
                time.sleep(lag)

    def est() -> dict:
        return cli.status("estimator") or {"values": {}, "level": -1, "message": ""}
    try:
        cli.wait_matched()
        # NaN outputs: counted and flagged, not fed as data
        publish(1.0, nan_every=20)
        cli.wait_for(lambda: int(est()["values"].get("nonfinite_samples", 0)) >= 10, 20, "non-finite count")
        assert "non-finite" in est()["values"]["reasons"]
        # count mismatch: 30 extra input messages, then every topic quiet
        for _ in range(30):
            cli.pubs["input"].publish(Float64(data=0.0))
        cli.wait_for(lambda: int(est()["values"].get("misaligned_events", 0)) >= 1, 20, "count-mismatch event")
        assert "count mismatch" in est()["values"]["reasons"]
        # silent reference while input and output continue: STALE naming the topic
        publish(1.5, signals=("input", "output"))
        e = est()
        assert e["level"] == 3 and "/reference" in e["values"]["silent_topics"], e
        assert cli.status("mode 1")["level"] == 3
        # back to normal: aligned samples flow again
        n0 = int(est()["values"]["samples_aligned"])
        publish(1.0)
        cli.wait_for(lambda: int(est()["values"]["samples_aligned"]) >= n0 + 150 and est()["level"] != 3, 20,
                     "recovery")
        # wrong message type on the reference topic
        ctx = Context()     # another participant: one participant cannot use two types on one topic
        rclpy.init(context=ctx, domain_id=dom)
        other = rclpy.create_node("rsrivc_wrong_type", context=ctx)
        try:
            other.create_publisher(String, "/reference", 10)
            cli.wait_for(lambda: "std_msgs/msg/String" in est()["values"].get("wrong_types", ""), 20, "wrong type")
            e = est()
            assert e["level"] == 2
            assert "/reference" in e["message"] and "std_msgs/msg/Float64" in e["message"], e["message"]
        finally:
            other.destroy_node()
            rclpy.try_shutdown(context=ctx)
        assert proc.poll() is None, "the node died"
    finally:
        cli.close()
        rc, out = stop_node(proc, "INT")
    assert rc == 0, out
    assert "Traceback" not in out


def test_cli_help_and_bad_params(tmp_path, ros_env):
    r = subprocess.run(["rsrivc_monitor", "--help"], capture_output=True, text=True, timeout=30, env=ros_env)
    assert r.returncode == 0 and r.stdout.startswith("usage: rsrivc_monitor")
    bad = tmp_path / "bad.yaml"
    bad.write_text("additive_rsrivc_monitor:\n  ros__parameters:\n    closed_loop: false\n"
                   "    modes:\n      natural_frequency_hz: [5.0]\n      damping_ratio: [0.1]\n      gain: [1.0]\n")
    r = subprocess.run(["rsrivc_monitor", "--ros-args", "--params-file", str(bad)], capture_output=True, text=True,
                       timeout=60, env=ros_env)
    assert r.returncode == 1 and "loop_rate_hz" in r.stderr and "Traceback" not in r.stderr + r.stdout
    for override, expect in (("modes.memory_sec:=[1.0]", "unknown parameter(s): modes.memory_sec"),
                             ("publish_rate_hz:=fast", "publish_rate_hz")):
        r = subprocess.run(["rsrivc_monitor", "--ros-args", "--params-file", PAPER, "-p", override],
                           capture_output=True, text=True, timeout=60, env=ros_env)
        assert r.returncode == 1 and expect in r.stderr and "Traceback" not in r.stderr, r.stderr
    r = subprocess.run(["rsrivc_monitor", "--bogus"], capture_output=True, text=True, timeout=30, env=ros_env)
    assert r.returncode == 2 and "--ros-args" in r.stderr


def test_cli_help_and_argument_errors_need_no_ros(ros_env):
    """--help and an argument error are answered before ROS is imported: with rclpy and the message packages made
    unimportable the console script's main still prints the usage (0) or one line (2)."""
    block = ("import sys\nfor m in ('rclpy', 'std_msgs', 'sensor_msgs', 'diagnostic_msgs', 'std_srvs', "
             "'rcl_interfaces'):\n    sys.modules[m] = None\n"
             "from additive_rsrivc_ros.node import main\nsys.exit(main(sys.argv[1:]))\n")
    r = subprocess.run([sys.executable, "-c", block, "--help"], capture_output=True, text=True, timeout=60,
                       env=ros_env)
    assert r.returncode == 0 and r.stdout.startswith("usage: rsrivc_monitor"), r.stdout + r.stderr
    r = subprocess.run([sys.executable, "-c", block, "--bogus"], capture_output=True, text=True, timeout=60,
                       env=ros_env)
    assert r.returncode == 2 and "--ros-args" in r.stderr and "Traceback" not in r.stderr, r.stderr
    r = subprocess.run([sys.executable, "-c", block, "--ros-args"], capture_output=True, text=True, timeout=60,
                       env=ros_env)
    lines = r.stderr.strip().splitlines()      # past the arguments ROS is needed: one line says what to install
    assert r.returncode == 1 and len(lines) == 1 and "no module rclpy" in lines[0] and "[ros]" in lines[0], r.stderr


@pytest.mark.parametrize("params", [*sorted(p.name for p in (REPO / "config").glob("*.yaml")
                                             if not p.name.startswith("diagnostic_aggregator")), "written"])
def test_every_bundled_params_file_configures_the_node_in_a_namespace(params, ros_env, tmp_path):
    """The rcl YAML parser (not only config.load_params_file) accepts each file and its section reaches the node in
    a namespace (/axis1, as ``monitor.launch.py namespace:=axis1`` starts it; the root namespace is what the other
    node tests use): the node activates; a file without mode guesses (e.g. beam_plant.yaml) configures for the
    automatic start (test_node_autostart.py). ``written``: a params file as rsrivc_identify --out-params writes it
    (config.render_params_yaml, here of the paper example)."""
    path = REPO / "config" / params
    if params == "written":
        path = tmp_path / "written.yaml"
        path.write_text(render_params_yaml(load_params_file(PAPER), header="written by the test"))
    no_guesses = not load_params_file(path)["modes.natural_frequency_hz"]
    proc = start_node(ros_env, str(path), ros_args=("-r", "__ns:=/axis1"))
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
    assert "configured:" in text and rc == 0 and "Traceback" not in text, text
    assert ("configured: K=from the data" in text) == no_guesses, text


def test_use_sim_time_follows_rsrivc_replay_clock(ros_env, tmp_path):
    """With use_sim_time the node's outputs are stamped in bag time (rsrivc_replay --clock), and every sample of
    the bag (Float64, replayed 10x faster than recorded) reaches the estimator."""
    from additive_rsrivc_ros.io.bagio import DEFAULT_T0_NS

    dom = int(ros_env["ROS_DOMAIN_ID"])
    sc = scenarios.build("paper_example", duration_s=40.0, seed=5)
    bag = sc.write_bag(tmp_path / "paper")
    proc = start_node(ros_env, PAPER, "use_sim_time:=true", "qos_depth:=5000")
    cli = Client(dom, Float64)
    try:
        cli.wait_matched()
        rep = subprocess.run(["rsrivc_replay", str(bag), "--rate", "10", "--clock", "--topics", "/reference",
                              "/plant_input", "/plant_output", "--wait-for-subscribers", "30"], env=ros_env,
                             capture_output=True, text=True, timeout=120)
        assert rep.returncode == 0, rep.stderr
        cli.wait_for(lambda: (cli.status("estimator") or {"values": {}})["values"].get("samples_aligned")
                     == str(sc.t.size), 30, "all samples aligned")
        stamp = cli.diags[-1].header.stamp
        t_ns = stamp.sec * 10**9 + stamp.nanosec
        bag_end = DEFAULT_T0_NS + int(sc.t[-1] * 1e9)
        assert DEFAULT_T0_NS <= t_ns <= bag_end + 10**9, (t_ns, DEFAULT_T0_NS, bag_end)
    finally:
        cli.close()
        rc, out = stop_node(proc, "INT")
    assert rc == 0, out


def test_manual_lifecycle_without_autostart(ros_env):
    """autostart false: the node waits unconfigured; configure + activate through the lifecycle service."""
    from lifecycle_msgs.msg import Transition
    from lifecycle_msgs.srv import ChangeState, GetState

    dom = int(ros_env["ROS_DOMAIN_ID"])
    proc = start_node(ros_env, PAPER, "autostart:=false")
    cli = Client(dom, Float64)
    try:
        st = cli._call(GetState, "/additive_rsrivc_monitor/get_state", GetState.Request())
        assert st.current_state.label == "unconfigured"
        time.sleep(1.0)
        assert not cli.diags, "an unconfigured node must not publish"
        for tid in (Transition.TRANSITION_CONFIGURE, Transition.TRANSITION_ACTIVATE):
            req = ChangeState.Request()
            req.transition.id = tid
            assert cli._call(ChangeState, "/additive_rsrivc_monitor/change_state", req).success
        assert cli._call(GetState, "/additive_rsrivc_monitor/get_state", GetState.Request()).current_state.label \
            == "active"
        cli.wait_for(lambda: cli.status("estimator") is not None, 20, "diagnostics after activation")
        req = ChangeState.Request()
        req.transition.id = Transition.TRANSITION_DEACTIVATE
        assert cli._call(ChangeState, "/additive_rsrivc_monitor/change_state", req).success
    finally:
        cli.close()
        rc, out = stop_node(proc, "INT")
    assert rc == 0 and "Traceback" not in out, out
