"""rsrivc_monitor over real DDS (issue 13, "never confidently wrong"): a refused state file is kept and the run's
state saved beside it, a state saved under another controller is refused, an early SIGINT exits cleanly, an
absent topic keeps the queues bounded with a drop counter on /diagnostics, and a publisher at half the loop rate
is a WARN naming the topic and both rates."""
import json
import re
import signal
import threading
import time
from pathlib import Path

import numpy as np
from std_msgs.msg import Float64
from test_node_helpers import Client, start_node, stop_node  # noqa: E402

from additive_rsrivc_ros.config import MonitorConfig, load_params_file
from additive_rsrivc_ros.core.monitor.pipeline import MonitorPipeline

REPO = Path(__file__).resolve().parents[1]
PAPER = str(REPO / "config" / "paper_example.yaml")


def _state_doc(node: str = "/additive_rsrivc_monitor", **overrides) -> str:
    params = {**load_params_file(PAPER), **overrides}
    return json.dumps({"node": node, "pipeline": MonitorPipeline(MonitorConfig.from_params(params)).get_state()})


def _run_briefly(env: dict, *overrides: str) -> str:
    proc = start_node(env, PAPER, *overrides)
    lines = []
    t_end = time.monotonic() + 60
    while time.monotonic() < t_end:
        line = proc.stdout.readline()
        if not line:
            break
        lines.append(line)
        if "configured:" in line:
            break
    rc, out = stop_node(proc, "TERM")
    text = "".join(lines) + out
    assert rc == 0 and "Traceback" not in text, text
    return text


def test_refused_state_file_is_kept_and_the_run_saves_beside_it(ros_env, tmp_path):
    # saved under another controller: refused with the reason, the file untouched, this run's state beside it
    state = tmp_path / "state.json"
    other = _state_doc(**{"controller.numerator": [0.03, -0.02, 0.004]})
    state.write_text(other)
    out = _run_briefly(ros_env, f"state_file:={state}")
    refused = [ln for ln in out.splitlines() if " refused (" in ln]
    assert len(refused) == 1 and "controller.numerator" in refused[0] and "kept unchanged" in refused[0], out
    assert state.read_text() == other
    beside = sorted(tmp_path.glob("state.*.json"))
    assert len(beside) == 1 and str(beside[0]) in refused[0]
    cfg = MonitorConfig.from_params(load_params_file(PAPER))
    MonitorPipeline(cfg, state=json.loads(beside[0].read_text())["pipeline"])      # a valid state of this model
    # another input delay and a corrupt file: refused the same way, never overwritten
    for content, why in ((_state_doc(input_delay_samples=2), "input_delay_samples"),
                         (_state_doc("/axis2/additive_rsrivc_monitor"), "written by node /axis2/"),
                         ('{"pipeline": {"version": 1, "K"', "unreadable")):
        for f in tmp_path.glob("state.*.json"):
            f.unlink()
        state.write_text(content)
        out = _run_briefly(ros_env, f"state_file:={state}")
        assert state.read_text() == content
        assert any(" refused (" in ln and why in ln for ln in out.splitlines()), out
        assert len(list(tmp_path.glob("state.*.json"))) == 1
    # a matching state is restored (and saved back in place)
    state.write_text(_state_doc())
    out = _run_briefly(ros_env, f"state_file:={state}")
    assert "state restored from" in out and " refused (" not in out, out
    assert json.loads(state.read_text())["pipeline"]["model"]["controller_numerator"] == \
        load_params_file(PAPER)["controller.numerator"]


def test_early_sigint_exits_cleanly_and_keeps_the_state(ros_env, tmp_path):
    state = tmp_path / "state.json"
    doc = _state_doc()
    state.write_text(doc)
    for delay in (0.3, 1.5):
        proc = start_node(ros_env, PAPER, f"state_file:={state}")
        time.sleep(delay)
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=60)
        assert "Traceback" not in out and "KeyboardInterrupt" not in out, out
        # exit 0 with one line; or, on a loaded machine, the signal landed during the interpreter's own start-up
        # (before any code of the package ran: default action, no output, nothing loaded or written)
        assert proc.returncode == 0 or (proc.returncode == -2 and not out.strip()), (proc.returncode, out)
        assert proc.returncode != 0 or "stopping (SIGINT)" in out, out
        cfg = MonitorConfig.from_params(load_params_file(PAPER))
        MonitorPipeline(cfg, state=json.loads(state.read_text())["pipeline"])     # valid, restorable
        assert not list(tmp_path.glob(".state.json.tmp*")), "a temporary file was left behind"


def _publish(cli: Client, rate: float, seconds: float, signals=("reference", "input", "output")) -> None:
    rng = np.random.default_rng(1)
    t0 = time.monotonic()
    for j in range(int(seconds * rate)):
        for s in signals:
            cli.pubs[s].publish(Float64(data=float(rng.standard_normal())))
        lag = t0 + (j + 1) / rate - time.monotonic()
        if lag > 0:
            time.sleep(lag)


def test_absent_topic_bounded_queue_with_drop_counter(ros_env):
    dom = int(ros_env["ROS_DOMAIN_ID"])
    rate = 400.0
    proc = start_node(ros_env, PAPER, f"loop_rate_hz:={rate}", "sync.stall_s:=0.2", "sync.max_backlog_s:=0.05",
                      "sync.max_queue_s:=0.5", "stale_timeout_s:=0.5", "publish_rate_hz:=5.0", "qos_depth:=100")
    cli = Client(dom, Float64)
    try:
        cli.wait_matched()
        _publish(cli, rate, 3.0, signals=("input", "output"))          # /reference never published
        bound = int(rate * 0.5)

        def dropped() -> dict:
            v = (cli.status("estimator") or {"values": {}})["values"]
            return dict(kv.split("=") for kv in v.get("queue_dropped_per_topic", "").split()) if v else {}
        cli.wait_for(lambda: int(dropped().get("/plant_input", 0)) >= 3 * rate - 2 * bound, 30, "drop counter")
        d = dropped()
        assert int(d["/reference"]) == 0 and int(d["/plant_output"]) >= 3 * rate - 2 * bound, d
        est = cli.status("estimator")
        assert int(est["values"]["queue_bound_samples"]) == bound
        assert int(est["values"]["queue_backlog"]) <= 2 * bound
        assert "/reference" in est["values"]["silent_topics"] and est["level"] == 3, est
    finally:
        cli.close()
        rc, out = stop_node(proc, "INT")
    assert rc == 0 and "Traceback" not in out, out
    full = [ln for ln in out.splitlines() if "queue of /plant_input full" in ln]
    assert len(full) == 1, out                                         # once per episode, not per message


def test_publisher_at_half_the_loop_rate_is_an_error_naming_the_topic(ros_env):
    """Float64 samples are timed by their arrival: at half loop_rate_hz the model's time scale would be wrong, so the
    estimator status is an ERROR naming the topic and the measured rate (and nothing is published)."""
    dom = int(ros_env["ROS_DOMAIN_ID"])
    proc = start_node(ros_env, PAPER, "loop_rate_hz:=200.0", "publish_rate_hz:=5.0")
    cli = Client(dom, Float64)
    pattern = re.compile(r"arrival rate (\d+) Hz on /plant_output, loop_rate_hz 200")
    try:
        cli.wait_matched()
        pub = threading.Thread(target=_publish, args=(cli, 100.0, 12.0))
        pub.start()
        found = []

        def warned() -> bool:
            est = cli.status("estimator") or {"message": "", "level": -1}
            if pattern.search(est["message"]) and est["level"] == 2 and "loop_rate_hz disagrees" in est["message"]:
                found.append(est)
            return bool(found)
        try:
            cli.wait_for(warned, 30, "the rate error while the data flows")
        finally:
            pub.join()
        est = found[0]
        measured = int(pattern.search(est["message"]).group(1))
        assert abs(measured - 100) <= 2, est                                # 2 % of the true rate
        assert int(est["values"]["rate_mismatches"]) >= 1
    finally:
        cli.close()
        rc, out = stop_node(proc, "INT")
    assert rc == 0 and "Traceback" not in out, out
    assert sum("arrival rate" in ln and "/plant_output" in ln for ln in out.splitlines()) == 1, out


def test_two_nodes_of_one_name_are_warned(ros_env):
    """Two monitors with the same fully qualified name in one graph: both say so (their statuses would mix)."""
    def until_configured(proc) -> str:
        lines, t_end = [], time.monotonic() + 120
        while time.monotonic() < t_end and (line := proc.stdout.readline()):
            lines.append(line)
            if "configured:" in line:
                break
        return "".join(lines)
    first = start_node(ros_env, PAPER)
    second = start_node(ros_env, PAPER)
    heads = [until_configured(p) for p in (first, second)]
    time.sleep(4.0)       # the check after activation, once discovery has seen both
    outs = [h + stop_node(p, "TERM")[1] for h, p in zip(heads, (first, second), strict=True)]
    assert all("2 nodes named /additive_rsrivc_monitor" in out for out in outs), outs
    # a node alone in its graph (another namespace) is not warned
    alone = start_node(ros_env, PAPER, ros_args=("-r", "__ns:=/axis7"))
    head = until_configured(alone)
    time.sleep(4.0)
    assert "nodes named" not in head + stop_node(alone, "TERM")[1]
