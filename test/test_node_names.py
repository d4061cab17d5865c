"""rsrivc_monitor under ROS naming conventions (issue 14), over real DDS (localhost, own domain).

* Two monitors in the namespaces /axis1 and /axis2 started from ONE params file (a ``/**`` section holding another
  node's parameters, ``/**/additive_rsrivc_monitor`` with the shared plant settings, ``/axis2/...`` overrides) with
  the default, relative topic names; one replay feeds two different simulated plants (000 §5 plant; axis 2 with
  mode 3 already 15 % lower) into /axis1/... and /axis2/.... Each monitor must equal the offline pipeline on its own
  plant's data, be near its own truth (the node tests' tolerance, 4 x the validated error level) and far from the
  other axis's mode 3, and count exactly its own samples: nothing crosses.
* QoS: ``qos_overrides./plant_output.subscription.reliability:=best_effort`` makes that subscription BEST_EFFORT
  (seen through the graph API from another process) while the other two stay RELIABLE.
* /diagnostics at ``diagnostics_period_s`` (wall time) independently of ~/modes (every report, ``publish_rate_hz`` in
  the data's time): a ratio of counts.
* A missing ``loop_rate_hz`` under a namespace names the params-file keys (one line).
"""
import subprocess
import time
from pathlib import Path

import numpy as np
from bag_variants import write_topics
from rclpy.qos import ReliabilityPolicy
from std_msgs.msg import Float64
from test_node_helpers import Client, start_node, stop_node  # noqa: E402

from additive_rsrivc_ros.config import MonitorConfig, load_params_file
from additive_rsrivc_ros.core.monitor.pipeline import MonitorPipeline
from additive_rsrivc_ros.io.bagio import DEFAULT_T0_NS
from additive_rsrivc_ros.sim import scenarios
from additive_rsrivc_ros.sim.experiments import LIMITS

REPO = Path(__file__).resolve().parents[1]
PAPER = REPO / "config" / "paper_example.yaml"
NO_DRIFT = {"drift1_start_s": 1e4, "drift1_end_s": 1.1e4}
SIGNALS = (("reference", "r"), ("plant_input", "u"), ("plant_output", "y"))


def _shared_params(path: Path) -> Path:
    """One params file for both axes: another node's parameters under /**, the paper plant under
    /**/additive_rsrivc_monitor (no topic names: the relative defaults), axis 2's own mode guesses."""
    body = PAPER.read_text().split("ros__parameters:", 1)[1]
    path.write_text("/**:\n  ros__parameters:\n    robot_description: \"<robot/>\"\n    joint_names: [\"a\", \"b\"]\n"
                    "/**/additive_rsrivc_monitor:\n  ros__parameters:" + body +
                    "/axis2/additive_rsrivc_monitor:\n  ros__parameters:\n    modes:\n"
                    "      natural_frequency_hz: [0.3183099, 0.7957747, 2.7]\n")
    return path


def _offline(sc, f3_guess: float) -> list:
    """The offline pipeline's reports on ``sc`` with the node's settings (the reference of the node's ~/modes)."""
    params = load_params_file(PAPER)
    params["modes.natural_frequency_hz"] = [0.3183099, 0.7957747, f3_guess]
    return MonitorPipeline(MonitorConfig.from_params(params)).push(sc.t, sc.r, sc.u, sc.y)


def test_two_axes_in_namespaces_from_one_params_file(ros_env, tmp_path):
    dom = int(ros_env["ROS_DOMAIN_ID"])
    params = _shared_params(tmp_path / "axes.yaml")
    plants = {"axis1": scenarios.build("paper_example", duration_s=160.0, seed=5, drift2_start_s=1.2e4,
                                       drift2_end_s=1.3e4, **NO_DRIFT),
              "axis2": scenarios.build("paper_example", duration_s=160.0, seed=6, drift2_start_s=-300.0,
                                       drift2_end_s=-200.0, **NO_DRIFT)}    # mode 3: -15 % (and zeta3 -30 %) from t=0
    streams = {}
    for ax, sc in plants.items():
        t_ns = DEFAULT_T0_NS + np.rint(sc.t * 1e9).astype(np.int64)
        streams.update({f"/{ax}/{name}": (t_ns, getattr(sc, v)) for name, v in SIGNALS})
    bag = write_topics(tmp_path / "axes", streams)
    procs = {ax: start_node(ros_env, str(params), "use_sim_time:=true", "qos_depth:=5000",
                            ros_args=("-r", f"__ns:=/{ax}")) for ax in plants}
    clis = {ax: Client(dom, Float64, ns=ax) for ax in plants}
    try:
        for cli in clis.values():
            cli.wait_matched()
        for ax in plants:      # exactly one subscriber per axis topic: that axis's monitor (names come late)
            def subscribers(ax=ax) -> list:
                return [(i.node_namespace, i.node_name)
                        for i in clis[ax].node.get_subscriptions_info_by_topic(f"/{ax}/plant_output")]
            clis[ax].wait_for(lambda ax=ax, f=subscribers: f() == [(f"/{ax}", "additive_rsrivc_monitor")], 20,
                              f"the only subscriber of /{ax}/plant_output to be /{ax}/additive_rsrivc_monitor")
        rep = subprocess.run(["rsrivc_replay", str(bag), "--rate", "10", "--clock", "--topics", *streams,
                              "--wait-for-subscribers", "30"], env=ros_env, capture_output=True, text=True,
                             timeout=180)
        assert rep.returncode == 0, rep.stderr
        refs = {"axis1": _offline(plants["axis1"], 3.1830989)[-20:], "axis2": _offline(plants["axis2"], 2.7)[-20:]}
        for ax, cli in clis.items():
            def matched(cli=cli, ax=ax) -> bool:
                return bool(cli.modes) and any(np.allclose(np.asarray(cli.modes[-1].data), r.modal.ravel(),
                                                           rtol=1e-6, atol=0.0) for r in refs[ax])
            cli.wait_for(matched, 60, f"{ax}: ~/modes equal to the offline pipeline on {ax}'s own plant")
        tol = 4 * LIMITS / 100
        for ax, cli in clis.items():
            other = "axis2" if ax == "axis1" else "axis1"
            modal = np.asarray(cli.modes[-1].data).reshape(3, 6)[:, :3]
            own, foreign = plants[ax].truth[:, -1, :], plants[other].truth[:, -1, :]
            rel = np.abs(modal - own) / np.abs(own)
            # frequencies and damping ratios on the truth; the gains only through the equality with the offline
            # pipeline above (axis 2 after 160 s: mode-3 gain 13.8 % off, beyond the 1000-s-run limit of 5.2 %,
            # the offline pipeline's own error on this short record with the 17.5 rad/s sine at its resonance)
            assert np.all(rel[:, :2] <= tol[:, :2]), (ax, "off its own truth by (%)", np.round(100 * rel, 2))
            # the plants differ in mode 3's frequency by far more than the tolerance: a crossed stream would show
            assert abs(modal[2, 0] - foreign[2, 0]) / foreign[2, 0] > 2 * tol[2, 0], (ax, modal[2, 0])
            est = cli.status("estimator")
            assert est is not None, f"no '{cli.target}: estimator' status on /diagnostics"
            assert est["hardware_id"] == f"/{ax}/additive_rsrivc_monitor"      # the default: the full node name
            assert int(est["values"]["samples_aligned"]) == plants[ax].t.size, (ax, est["values"])
            assert est["values"]["wrong_types"] == ""
            # the replay has ended: the silence check names this axis's resolved topics, and only them
            silent = f"/{ax}/reference /{ax}/plant_input /{ax}/plant_output"
            cli.wait_for(lambda cli=cli, s=silent: cli.status("estimator")["values"]["silent_topics"] == s, 20,
                         f"STALE naming {silent}")
    finally:
        for cli in clis.values():
            cli.close()
        outs = {ax: stop_node(p, "INT") for ax, p in procs.items()}
    for ax, (rc, out) in outs.items():
        assert rc == 0 and "Traceback" not in out, out
        # the other node's parameters in the /** section are warned about in one line, not fatal
        assert sum("ignoring parameter(s)" in line for line in out.splitlines()) == 1, out
        assert f"inputs /{ax}/reference, /{ax}/plant_input, /{ax}/plant_output" in out, out


def test_qos_override_and_diagnostics_period(ros_env, tmp_path):
    """plant_output BEST_EFFORT by the standard qos_overrides parameter, the others RELIABLE (graph API); with
    publish_rate_hz 10 and diagnostics_period_s 1 and the data replayed 10x, ~/modes goes out ~100x as often."""
    dom = int(ros_env["ROS_DOMAIN_ID"])
    sc = scenarios.build("paper_example", duration_s=130.0, seed=5)
    bag = sc.write_bag(tmp_path / "paper")
    proc = start_node(ros_env, str(PAPER), "use_sim_time:=true", "qos_depth:=5000", "publish_rate_hz:=10.0",
                      "diagnostics_period_s:=1.0", "qos_overrides./plant_output.subscription.reliability:=best_effort",
                      "hardware_id:=axis-7 drive SN 0042")
    cli = Client(dom, Float64)
    play = None
    try:
        cli.wait_matched()
        kinds = {}
        for topic in ("/reference", "/plant_input", "/plant_output"):
            infos = cli.node.get_subscriptions_info_by_topic(topic)
            assert len(infos) == 1, (topic, infos)
            kinds[topic] = infos[0].qos_profile.reliability
        assert kinds == {"/reference": ReliabilityPolicy.RELIABLE, "/plant_input": ReliabilityPolicy.RELIABLE,
                         "/plant_output": ReliabilityPolicy.BEST_EFFORT}, kinds
        play = subprocess.Popen(["rsrivc_replay", str(bag), "--rate", "10", "--clock", "--topics", "/reference",
                                 "/plant_input", "/plant_output", "--wait-for-subscribers", "30"], env=ros_env,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        cli.wait_for(lambda: len(cli.modes) > 0, 60, "the first ~/modes message (end of the initialization)")
        n0 = (len(cli.modes), len(cli.diags))
        time.sleep(4.0)                          # a window while the data stream (the bag lasts 13 s of wall time)
        n1 = (len(cli.modes), len(cli.diags))
        _, err = play.communicate(timeout=120)
        assert play.returncode == 0, err
        # ~/modes carries every report: publish_rate_hz (10) per second of data, and the data come 10x faster than
        # real time (100 per wall second); /diagnostics once per wall second: a ratio of about 100. Tied to one
        # publish cycle (as before issue 14) /diagnostics would come at 10 Hz (ratio 10).
        n_modes, n_diag = n1[0] - n0[0], n1[1] - n0[1]
        assert n_diag >= 2 and 40.0 <= n_modes / n_diag <= 250.0, (n_modes, n_diag)
        cli.wait_for(lambda: int(cli.status("estimator")["values"]["samples_aligned"]) >= 0.9 * sc.t.size, 30,
                     "the samples aligned (a best-effort plant_output still delivers on loopback)")
        # the hardware_id parameter names the device of every status (default: the node's full name)
        assert {cli.status(s)["hardware_id"] for s in ("estimator", "mode 1", "mode 3")} == {"axis-7 drive SN 0042"}
    finally:
        if play is not None and play.poll() is None:
            play.kill()
            play.communicate()
        cli.close()
        rc, out = stop_node(proc, "INT")
    assert rc == 0, out
    assert "/plant_output best_effort" in out and "/reference reliable" in out, out


def _rosout_listener(dom: int) -> tuple[Client, list]:
    """A client node that records /rosout (rosout's QoS: reliable, transient local)."""
    from rcl_interfaces.msg import Log

    from additive_rsrivc_ros.ros.rosout import ROSOUT_QOS

    cli = Client(dom, Float64)
    logs: list = []
    cli.node.create_subscription(Log, "/rosout", logs.append, ROSOUT_QOS)
    return cli, logs


def test_missing_rate_under_a_namespace_names_the_params_key(ros_env, tmp_path):
    """A plain key 'additive_rsrivc_monitor' reaches only the root namespace: under /axis1 the node gets no
    parameters and must say which one is missing and which keys would work, in one line on stderr, and the same
    as a FATAL record of the node's logger on /rosout."""
    from rcl_interfaces.msg import Log

    plain = tmp_path / "plain.yaml"
    plain.write_text(PAPER.read_text().replace("/**/additive_rsrivc_monitor:", "additive_rsrivc_monitor:"))
    assert "\nadditive_rsrivc_monitor:" in plain.read_text()
    cli, logs = _rosout_listener(int(ros_env["ROS_DOMAIN_ID"]))
    try:
        r = subprocess.run(["rsrivc_monitor", "--ros-args", "-r", "__ns:=/axis1", "--params-file", str(plain)],
                           capture_output=True, text=True, timeout=60, env=ros_env)
        lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
        assert r.returncode == 1 and "Traceback" not in r.stderr + r.stdout, r.stderr
        reason = ("parameter 'loop_rate_hz' is required (no params for node '/axis1/additive_rsrivc_monitor': the "
                  "YAML key must be '/**/additive_rsrivc_monitor' or '/axis1/additive_rsrivc_monitor')")
        assert lines == [f"rsrivc_monitor: {reason}"], r.stderr
        cli.wait_for(lambda: any(m.level == Log.FATAL for m in logs), 30.0, "the fatal error on /rosout")
        fatal = [m for m in logs if m.level == Log.FATAL]
        assert [(m.name, m.msg) for m in fatal] == [("axis1.additive_rsrivc_monitor", reason)]
    finally:
        cli.close()


def test_stop_notice_reaches_rosout(ros_env):
    """SIGINT: 'stopping (SIGINT)' on stderr and as an INFO record of the node's logger on /rosout."""
    from rcl_interfaces.msg import Log

    cli, logs = _rosout_listener(int(ros_env["ROS_DOMAIN_ID"]))
    proc = start_node(ros_env, str(PAPER), ros_args=("-r", "__ns:=/axis1"))
    try:
        cli.wait_for(lambda: any("configured:" in m.msg for m in logs), 60.0, "the node's configured line")
        rc, out = stop_node(proc, "INT")
        assert rc == 0 and "rsrivc_monitor: stopping (SIGINT)" in out, out
        cli.wait_for(lambda: any(m.msg == "stopping (SIGINT)" for m in logs), 30.0, "the stop notice on /rosout")
        notice = [m for m in logs if m.msg == "stopping (SIGINT)"]
        assert len(notice) == 1 and notice[0].level == Log.INFO and notice[0].name == "axis1.additive_rsrivc_monitor"
    finally:
        if proc.poll() is None:
            stop_node(proc, "INT")
        cli.close()
