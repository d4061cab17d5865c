"""rsrivc_monitor without mode guesses, over real DDS (localhost, own domain): the automatic start in the node.

A params file with only rate, controller, delay and memory (no ``modes.natural_frequency_hz``) and stamped inputs
carrying a simulated closed loop (test_frf's plant and controller, test_modefind's excitation) whose setpoint is
constant for the first window: while no mode is known the node publishes no ~/modes message and no mode status, its
estimator status says why (STALE while collecting, the failed window's reason after it); once the setpoint moves,
the modes are found on the next window (one log line), /diagnostics carries one ``<node>: mode i`` status per mode
found with frequencies near the truth (the modefind tests' 1 %) and ~/modes has K rows.
"""
import time

import numpy as np
from frf_cases import CONTROLLER, DELAY, FS, MODES, no_guess_params_yaml
from sensor_msgs.msg import JointState
from test_node_helpers import Client, start_node, stop_node  # noqa: E402

from additive_rsrivc_ros.sim.simulate import simulate_modes, square_wave, white_noise

STAMPED = [f"{s}.type:=sensor_msgs/msg/JointState" for s in ("reference", "input", "output")]
PARAMS = no_guess_params_yaml("    qos_depth: 20000\n")
FLAT_S, DURATION_S = 5.0, 12.0


def _record():
    rng = np.random.default_rng(5)
    t = np.arange(int(DURATION_S * FS)) / FS
    r = square_wave(t, 0.5, 1.0) + white_noise(t.size, 0.05, rng)
    r[t < FLAT_S] = 0.3                    # a resting setpoint: the first window excites nothing
    sim = simulate_modes(MODES, FS, r=r, controller=CONTROLLER, input_delay=DELAY,
                         noise=white_noise(t.size, 0.01, rng), rng=rng)
    return {"reference": sim.r, "input": sim.u, "output": sim.y}


def _publish(cli: Client, data: dict, a: int, b: int) -> None:
    t0_ns, h_ns = 1_000 * 10**9, int(round(1e9 / FS))
    for k in range(a, b):
        ns = t0_ns + k * h_ns
        for s, p in cli.pubs.items():
            m = JointState()
            m.header.stamp.sec, m.header.stamp.nanosec = ns // 10**9, ns % 10**9
            m.name, m.position = ["j"], [float(data[s][k])]
            p.publish(m)
        if k % 200 == 199:
            time.sleep(0.03)


def test_node_without_guesses_finds_the_modes_and_publishes_nothing_before(ros_env, tmp_path):
    params = tmp_path / "no_guesses.yaml"
    params.write_text(PARAMS)
    data = _record()
    proc = start_node(ros_env, str(params), *STAMPED)
    cli = Client(int(ros_env["ROS_DOMAIN_ID"]), JointState)
    try:
        cli.wait_matched()
        cli.wait_for(lambda: cli.status("estimator") is not None, 20, "the estimator status")
        assert cli.status("mode 1") is None and cli.status("estimator")["level"] == 3   # STALE: no data, no modes
        # the flat window and a little more: the search fails, says why, publishes nothing
        _publish(cli, data, 0, int((FLAT_S + 1.0) * FS))
        cli.wait_for(lambda: "no excitation" in (cli.status("estimator") or {"message": ""})["message"], 30,
                     "the estimator status saying why no modes were found")
        st = cli.status("estimator")
        assert st["level"] in (1, 3) and "no modes found on t=0.0–5.0 s" in st["message"], st["message"]
        assert st["values"]["phase"] == "finding modes"
        assert cli.status("mode 1") is None and not cli.modes
        # the moving setpoint: modes found on the next window, then tracked
        _publish(cli, data, int((FLAT_S + 1.0) * FS), int(DURATION_S * FS))
        cli.wait_for(lambda: cli.status("mode 2") is not None and
                     cli.status("mode 2")["values"]["natural_frequency_hz"] != "nan", 60,
                     "two mode statuses with estimates")
        assert cli.status("mode 3") is None
        for i, truth in enumerate(MODES, 1):
            f = float(cli.status(f"mode {i}")["values"]["natural_frequency_hz"])
            assert abs(f / truth.natural_frequency_hz - 1.0) < 0.01, (i, f)
        cli.wait_for(lambda: bool(cli.modes), 10, "~/modes")
        assert all([(d.label, d.size) for d in m.layout.dim] == [("mode", 2), ("field", 6)] for m in cli.modes)
        assert all(np.all(np.isfinite(m.data)) for m in cli.modes)   # never a NaN row before the model
    finally:
        last = cli.status("estimator")
        cli.close()
        rc, out = stop_node(proc, "INT")
        print(out, "\nlast estimator status:", last)   # shown when the test fails
    assert rc == 0, out
    assert "configured: K=from the data" in out
    found = [ln for ln in out.splitlines() if "no mode guesses: found 2 mode(s) on t=5.0–10.0 s" in ln]
    assert len(found) == 1, out
    assert "Traceback" not in out
